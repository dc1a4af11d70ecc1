//! `terrastream pack`: a finished tileset (directory or bucket prefix) into one archive file
//! (`.tsa`), local or uploaded to a bucket as one object.

use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use terrastream::store::{ARCHIVE_SUFFIX, Bucket, Store, check_out_file, is_remote};

#[derive(clap::Args)]
pub struct PackArgs {
    /// The finished tileset: a directory, file:// or s3://BUCKET/PREFIX.
    pub dir: PathBuf,
    /// The archive to write: a path or s3://BUCKET/KEY, ending in .tsa. An existing archive is
    /// replaced whole (written beside it and renamed; in a bucket, one atomic upload).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(a: &PackArgs, quiet: bool) -> Result<()> {
    let out = a.out.to_string_lossy().into_owned();
    if !out.ends_with(ARCHIVE_SUFFIX) {
        bail!(
            "pack --out {out}: an archive's name ends in {ARCHIVE_SUFFIX} (that is how `serve` and the other commands tell it from a folder)"
        );
    }
    if out.starts_with("http://") || out.starts_with("https://") {
        bail!(
            "pack --out {out}: a web server takes no uploads here; write the archive to a file or s3://BUCKET/KEY{ARCHIVE_SUFFIX} and publish it from there"
        );
    }
    let target_remote = is_remote(&out) && !out.starts_with("file://");
    let local_target = PathBuf::from(out.strip_prefix("file://").unwrap_or(&out));
    if !target_remote {
        // Before any work: a missing folder is named, not reported as a temporary file.
        check_out_file(&local_target)?;
    }
    let store = Store::at(&a.dir)?;
    if store.archive().is_some() {
        bail!("pack: {} is already an archive", a.dir.display());
    }
    let files = store.files()?;
    let total: u64 = files.iter().map(|(_, n)| n).sum();
    let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new(total) };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {bytes}/{total_bytes}  {bytes_per_sec}  ETA {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    let t0 = Instant::now();
    // Written beside the target under a temporary name, renamed into place when whole; for a
    // bucket, into the local temporary directory first and then uploaded as one object.
    let tmp = if target_remote {
        tempfile::Builder::new().prefix("terrastream-pack-").suffix(ARCHIVE_SUFFIX).tempfile()
    } else {
        let parent = local_target.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        // The mode every file of a bake gets (0666 less the umask, 0644 typically), not a
        // temporary file's 0600: a server running as another user must be able to read it.
        tempfile::Builder::new()
            .prefix(".pack-")
            .suffix(".tmp")
            .permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666))
            .tempfile_in(parent)
    }
    .with_context(|| format!("pack: cannot create a temporary file for {out}"))?;
    let file = tmp.as_file().try_clone().with_context(|| format!("pack: writing {out}"))?;
    let r = store.pack_into(BufWriter::new(file), |n| bar.inc(n));
    let (w, count, len) = match r {
        Ok(v) => v,
        Err(e) => {
            bar.finish_and_clear();
            return Err(e.into());
        }
    };
    w.into_inner()
        .map_err(std::io::IntoInnerError::into_error)
        .and_then(|f| f.sync_all())
        .with_context(|| format!("pack: writing {out}"))?;
    bar.finish_and_clear();
    if target_remote {
        let (parent, name) = out.rsplit_once('/').unwrap_or((&out, ""));
        let r = Bucket::open(parent)?;
        r.put_file(name, tmp.path())?;
    } else {
        tmp.persist(&local_target)
            .with_context(|| format!("pack: cannot move the archive into place at {out}"))?;
    }
    outln!(
        "packed {} files ({} bytes) of {} into {out}: {len} bytes, in {:.2} s",
        count,
        total,
        a.dir.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
