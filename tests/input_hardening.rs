//! Inputs hardened (issue 40, N5, N6, N10): hundreds of GeoTIFFs (and a VRT of them) bake under
//! a low open-file limit; a VRT, a mosaic or a point cloud mostly of no-data is refused saying
//! why unless `--allow-sparse`; a raster too small to tile, a LAS file of an undefined point
//! format or with absurd counts and offsets, and a missing S3 bucket get messages that name the
//! file (or bucket) and the problem.

#![allow(clippy::unwrap_used, clippy::panic, clippy::type_complexity)]

mod common;

use std::fmt::Write as _;
use std::io::{Read, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use common::{bin, fails, ok, run_within};
use terrastream::raster::geotiff::{Model, write_tiled_f32};
use terrastream::raster::synth::height_at;

/// A tiled float32 GeoTIFF of `w × h` samples at sample offset (c0, r0) of one grid (cells of 10).
fn tif(path: &Path, (w, h): (u32, u32), (c0, r0): (u32, u32)) {
    let mut f = std::fs::File::create(path).unwrap();
    let origin = (f64::from(c0) * 10.0, 100_000.0 - f64::from(r0) * 10.0);
    write_tiled_f32(&mut f, (w, h), 16, Model::Projected, origin, (10.0, -10.0), None, false, |c, r| {
        height_at(4096, 4096, 3, c + c0, r + r0)
    })
    .unwrap();
}

/// `terrastream ARGS` run under `ulimit -n limit`.
fn limited(limit: u32) -> Command {
    let mut c = Command::new("sh");
    c.arg("-c")
        .arg(format!("ulimit -n {limit} && exec \"$0\" \"$@\""))
        .arg(env!("CARGO_BIN_EXE_terrastream"));
    c.stdin(std::process::Stdio::null());
    c
}

const BAKE: [&str; 8] = ["--tile-size", "64", "--levels", "1", "--gpu", "off", "--threads", "2"];

/// N5: 300 GeoTIFFs (20 × 15 files of 16² samples), and a VRT of the same 300 files, bake
/// under `ulimit -n 64`: input files are not all kept open.
#[test]
fn hundreds_of_files_bake_under_a_low_open_file_limit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let tiles = d.join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    let mut vrt = String::from(
        "<VRTDataset rasterXSize=\"320\" rasterYSize=\"240\">\n  <SRS></SRS>\n  \
         <GeoTransform>-5.0, 10.0, 0.0, 100005.0, 0.0, -10.0</GeoTransform>\n  <VRTRasterBand dataType=\"Float32\" band=\"1\">\n",
    );
    for j in 0..15 {
        for i in 0..20 {
            let name = format!("t{j:02}-{i:02}.tif");
            tif(&tiles.join(&name), (16, 16), (i * 16, j * 16));
            let _ = writeln!(
                vrt,
                "    <SimpleSource><SourceFilename relativeToVRT=\"1\">tiles/{name}</SourceFilename><SourceBand>1</SourceBand>\
                 <SrcRect xOff=\"0\" yOff=\"0\" xSize=\"16\" ySize=\"16\"/><DstRect xOff=\"{}\" yOff=\"{}\" xSize=\"16\" ySize=\"16\"/></SimpleSource>",
                i * 16,
                j * 16
            );
        }
    }
    vrt += "  </VRTRasterBand>\n</VRTDataset>\n";
    std::fs::write(d.join("all.vrt"), vrt).unwrap();
    let a = d.join("a");
    let o = run_within(
        limited(64).args(["bake", "-q", "--out"]).arg(&a).arg(&tiles).args(BAKE),
        Duration::from_mins(5),
    );
    assert!(o.status.success(), "300 files under ulimit -n 64: {}", String::from_utf8_lossy(&o.stderr));
    let b = d.join("b");
    let o = run_within(
        limited(64).args(["bake", "-q", "--out"]).arg(&b).arg(d.join("all.vrt")).args(BAKE),
        Duration::from_mins(5),
    );
    assert!(
        o.status.success(),
        "a VRT of 300 files under ulimit -n 64: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    // Both read the same samples: the same blobs.
    let (ta, tb) = (common::blobs_and_index(&a), common::blobs_and_index(&b));
    assert!(ta.len() > 5 && ta == tb);
}

/// N6: a small VRT declaring a vast extent around one small source is refused with the numbers
/// and the opt-in; so are two files far apart and a sparse point cloud. `--allow-sparse` bakes.
#[test]
fn datasets_mostly_of_no_data_are_refused_unless_allowed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    tif(&d.join("s.tif"), (65, 65), (0, 0));
    let vrt = |size: u32, name: &str| {
        let text = format!(
            "<VRTDataset rasterXSize=\"{size}\" rasterYSize=\"{size}\"><SRS></SRS>\
             <GeoTransform>-5.0, 10.0, 0.0, 100005.0, 0.0, -10.0</GeoTransform><VRTRasterBand dataType=\"Float32\" band=\"1\">\
             <SimpleSource><SourceFilename relativeToVRT=\"1\">s.tif</SourceFilename><SourceBand>1</SourceBand>\
             <SrcRect xOff=\"0\" yOff=\"0\" xSize=\"65\" ySize=\"65\"/><DstRect xOff=\"0\" yOff=\"0\" xSize=\"65\" ySize=\"65\"/>\
             </SimpleSource></VRTRasterBand></VRTDataset>"
        );
        let p = d.join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let continent = vrt(1 << 20, "continent.vrt");
    let out = d.join("o1");
    let e = fails(bin().args(["bake", "-q", "--out"]).arg(&out).arg(&continent).args(BAKE));
    assert!(
        e.contains("continent.vrt")
            && e.contains("1048576×1048576")
            && e.contains("4225")
            && e.contains("--allow-sparse"),
        "{e}"
    );
    assert!(!out.exists());
    // A plan refuses it too (the flag is one `plan` records).
    let e = fails(bin().args(["plan", "-q", "--out"]).arg(d.join("p1")).arg(&continent));
    assert!(e.contains("--allow-sparse"), "{e}");
    // 600² around 65²: 85 samples per sample of data, refused; accepted when asked for.
    let wide = vrt(600, "wide.vrt");
    let e = fails(bin().args(["bake", "-q", "--out"]).arg(d.join("o2")).arg(&wide).args(BAKE));
    assert!(e.contains("wide.vrt") && e.contains("600×600") && e.contains("85 samples"), "{e}");
    ok(bin().args(["bake", "-q", "--allow-sparse", "--out"]).arg(d.join("o3")).arg(&wide).args(BAKE));
    // Within the bound: 400² around 65² (37 to 1).
    ok(bin().args(["bake", "-q", "--out"]).arg(d.join("o4")).arg(vrt(400, "fits.vrt")).args(BAKE));

    // Two files 5,000 cells apart.
    tif(&d.join("far.tif"), (65, 65), (5000, 5000));
    let e = fails(
        bin()
            .args(["bake", "-q", "--out"])
            .arg(d.join("o5"))
            .arg(d.join("s.tif"))
            .arg(d.join("far.tif"))
            .args(BAKE),
    );
    assert!(e.contains("s.tif") && e.contains("--allow-sparse") && e.contains("no-data"), "{e}");

    // A point cloud of two points 5 km apart at 1 m cells.
    let las = d.join("two.las");
    write_las(&las, &[(0.0, 0.0, 1.0), (5000.0, 5000.0, 2.0)], (1, 2));
    let e =
        fails(bin().args(["bake", "-q", "--cell-size", "1", "--out"]).arg(d.join("o6")).arg(&las).args(BAKE));
    assert!(e.contains("two.las") && e.contains("--allow-sparse") && e.contains("only 2 points"), "{e}");
}

/// Writes `points` as LAS `version`, point format 1, scale 0.01.
fn write_las(path: &Path, points: &[(f64, f64, f64)], version: (u8, u8)) {
    let mut b = las::Builder::from(version);
    b.point_format = las::point::Format::new(1).unwrap();
    let t = las::Transform { scale: 0.01, offset: 0.0 };
    b.transforms = las::Vector { x: t, y: t, z: t };
    let mut w = las::Writer::from_path(path, b.into_header().unwrap()).unwrap();
    for &(x, y, z) in points {
        w.write_point(las::Point { x, y, z, gps_time: Some(0.0), ..las::Point::default() }).unwrap();
    }
    w.close().unwrap();
}

/// N10: messages that name the file and the problem.
#[test]
fn inputs_too_small_or_with_absurd_headers_get_clear_messages() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (w, h) in [(1, 1), (1, 40), (40, 1)] {
        let name = format!("small-{w}x{h}.tif");
        let mut f = std::fs::File::create(d.join(&name)).unwrap();
        write_tiled_f32(
            &mut f,
            (w, h),
            16,
            Model::Projected,
            (0.0, 0.0),
            (1.0, -1.0),
            None,
            false,
            |_, _| 1.0,
        )
        .unwrap();
        let e = fails(bin().args(["bake", "-q", "--out"]).arg(d.join("o")).arg(d.join(&name)));
        assert!(e.contains(&name) && e.contains(&format!("{w}×{h}")) && e.contains("2×2"), "{e}");
    }

    let pts: Vec<(f64, f64, f64)> = (0..400).map(|i| (f64::from(i % 20), f64::from(i / 20), 5.0)).collect();
    let good12 = d.join("good12.las");
    write_las(&good12, &pts, (1, 2));
    let good14 = d.join("good14.las");
    write_las(&good14, &pts, (1, 4));
    let (las12, las14) = (std::fs::read(&good12).unwrap(), std::fs::read(&good14).unwrap());
    let patch = |bytes: &[u8], at: usize, with: &[u8]| {
        let mut b = bytes.to_vec();
        b[at..at + with.len()].copy_from_slice(with);
        b
    };
    // LAS header: VLR count at 100, point format at 104, legacy count at 107; LAS 1.4: first
    // EVLR at 235, EVLR count at 243, 64-bit count at 247.
    let cases: Vec<(&str, Vec<u8>, &[&str], &[&str])> = vec![
        (
            "format99.las",
            patch(&las12, 104, &[99]),
            &["LAS", "point data record format 99", "0 to 10"],
            &["LAZ file"],
        ),
        ("format163.las", patch(&las12, 104, &[163]), &["point data record format 163"], &["LAZ file"]),
        (
            "count.las",
            patch(&patch(&las14, 107, &0u32.to_le_bytes()), 247, &(1u64 << 40).to_le_bytes()),
            &["1099511627776 points", "68719476736"],
            &["os error"],
        ),
        (
            "evlr.las",
            patch(&patch(&las14, 235, &(1u64 << 63).to_le_bytes()), 243, &3u32.to_le_bytes()),
            &["extended variable length records", "9223372036854775808"],
            &["os error"],
        ),
        (
            "evlrs.las",
            patch(
                &patch(&las14, 235, &(las14.len() as u64 - 60).to_le_bytes()),
                243,
                &u32::MAX.to_le_bytes(),
            ),
            &["4294967295 extended variable length records"],
            &["os error"],
        ),
        (
            "vlrs.las",
            patch(&las12, 100, &u32::MAX.to_le_bytes()),
            &["4294967295 variable length records"],
            &["fill whole buffer"],
        ),
    ];
    for (name, bytes, want, not) in cases {
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        let out = d.join(format!("out-{name}"));
        let e = fails(bin().args(["bake", "-q", "--cell-size", "1", "--out"]).arg(&out).arg(&p));
        eprintln!("{name}: {}", e.trim());
        assert!(e.contains(name), "{name}: {e}");
        for w in want {
            assert!(e.contains(w), "{name}: wanted {w:?}: {e}");
        }
        for n in not {
            assert!(!e.contains(n), "{name}: {n:?} should not be said: {e}");
        }
        assert!(!out.exists(), "{name}: something was written");
    }
    // The good files still bake.
    ok(bin()
        .args(["bake", "-q", "--cell-size", "1", "--gpu", "off", "--out"])
        .arg(d.join("g12"))
        .arg(&good12));
    ok(bin()
        .args(["bake", "-q", "--cell-size", "1", "--gpu", "off", "--out"])
        .arg(d.join("g14"))
        .arg(&good14));
}

/// N10: a bucket that does not exist (an S3 server answering `NoSuchBucket`, as S3 and MinIO
/// do) is named in a sentence, not shown as the server's XML.
#[test]
fn a_missing_bucket_is_said_in_words() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let endpoint = format!("http://{}", listener.local_addr().unwrap());
    std::thread::spawn(move || {
        let body = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<Error><Code>NoSuchBucket</Code><Message>The specified \
                    bucket does not exist</Message><BucketName>nobucket</BucketName><RequestId>1</RequestId></Error>";
        for stream in listener.incoming() {
            let Ok(mut s) = stream else { continue };
            std::thread::spawn(move || {
                let _ = s.set_read_timeout(Some(Duration::from_secs(5)));
                let mut buf = [0u8; 4096];
                let mut head = Vec::new();
                // Read the request head (and whatever body came with it); answer 404 to anything.
                while !head.windows(4).any(|w| w == b"\r\n\r\n") {
                    match s.read(&mut buf) {
                        Ok(0) | Err(_) => return,
                        Ok(n) => head.extend_from_slice(&buf[..n]),
                    }
                }
                let is_head = head.starts_with(b"HEAD");
                let reply = format!(
                    "HTTP/1.1 404 Not Found\r\nContent-Type: application/xml\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{}",
                    body.len(),
                    if is_head { "" } else { body }
                );
                let _ = s.write_all(reply.as_bytes());
            });
        }
    });
    let dir = tempfile::tempdir().unwrap();
    let tif_path: PathBuf = dir.path().join("t.tif");
    tif(&tif_path, (65, 65), (0, 0));
    let s3 = |c: &mut Command| {
        c.env("AWS_ENDPOINT_URL", &endpoint)
            .env_remove("AWS_ENDPOINT_URL_S3")
            .env("AWS_ACCESS_KEY_ID", "test")
            .env("AWS_SECRET_ACCESS_KEY", "test")
            .env("AWS_REGION", "us-east-1")
            .env("TERRASTREAM_S3_RETRIES", "0");
    };
    let mut bake = bin();
    bake.args(["bake", "-q", "--gpu", "off", "--out", "s3://nobucket/ts"]).arg(&tif_path);
    s3(&mut bake);
    let mut inspect = bin();
    inspect.args(["inspect", "s3://nobucket/ts"]);
    s3(&mut inspect);
    for c in [&mut bake, &mut inspect] {
        let e = fails(c);
        assert!(e.contains("bucket nobucket does not exist"), "{e}");
        assert!(!e.contains("<?xml") && !e.contains("<Code>"), "{e}");
    }
}

/// The binary raises its soft open-file limit to the hard one: a shell's soft 64 (hard left
/// as it is) does not hold a server or a bake of a large mosaic to 64 descriptors.
#[cfg(target_os = "linux")]
#[test]
fn the_soft_open_file_limit_is_raised_to_the_hard_one() {
    let limits = |pid: u32| {
        let text = std::fs::read_to_string(format!("/proc/{pid}/limits")).unwrap();
        let line = text.lines().find(|l| l.starts_with("Max open files")).unwrap().to_owned();
        let mut f = line.trim_start_matches("Max open files").split_whitespace();
        (f.next().unwrap().to_owned(), f.next().unwrap().to_owned())
    };
    let (_, hard) = limits(std::process::id());
    if hard != "unlimited" && hard.parse::<u64>().unwrap() <= 64 {
        eprintln!("skipping: the hard open-file limit here is {hard}");
        return;
    }
    let store = tempfile::tempdir().unwrap();
    let mut c = Command::new("sh");
    c.arg("-c")
        .arg("ulimit -S -n 64 && exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_terrastream"))
        .args(["--quiet", "serve", "--store"])
        .arg(store.path());
    let served = common::serve(c);
    let (soft, hard_seen) = limits(served.child.id());
    assert_eq!(hard_seen, hard);
    if hard == "unlimited" {
        assert_eq!(soft, "64", "an unlimited hard limit is left alone");
    } else {
        assert_eq!(soft, hard, "the soft limit was not raised");
    }
}
