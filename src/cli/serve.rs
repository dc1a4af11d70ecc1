//! `terrastream serve`: a store directory of tilesets over HTTP.

use std::path::PathBuf;

use anyhow::Result;
use terrastream::server;

/// `serve`'s flags are the server's [`server::PartialConfig`]; unset ones come from the TOML
/// file (--config), then the defaults. Environment variables count as flags.
#[derive(clap::Args)]
pub struct ServeArgs {
    #[command(flatten)]
    pub settings: server::PartialConfig,
    #[arg(
        long,
        env = "TERRASTREAM_CONFIG",
        help = "TOML file with the same settings (snake_case keys); flags and environment win"
    )]
    pub config: Option<PathBuf>,
    /// The file's settings, read once: a pipe (`--config <(…)`) reads empty the second time,
    /// and the log format is looked up before the server starts.
    #[arg(skip)]
    pub file: std::sync::OnceLock<Result<server::PartialConfig, String>>,
}

impl ServeArgs {
    /// Flags and environment over the TOML file over the defaults.
    pub fn config(&self) -> Result<server::Config> {
        let file = match &self.config {
            Some(p) => self
                .file
                .get_or_init(|| server::PartialConfig::from_toml_file(p).map_err(|e| e.to_string()))
                .clone()
                .map_err(anyhow::Error::msg)?,
            None => server::PartialConfig::default(),
        };
        Ok(self.settings.clone().over(file).resolve()?)
    }
}

pub fn run(a: &ServeArgs) -> Result<()> {
    let config = a.config()?;
    server::serve_blocking(config, |addr, app| print_urls(addr, &app.tileset_names()))?;
    Ok(())
}

/// The URLs to try, printed when the server is listening.
pub fn print_urls(addr: std::net::SocketAddr, names: &[String]) {
    let first = names.first().map_or(String::new(), |n| format!("?tileset={n}"));
    outln!("viewer: http://{addr}/viewer{first}  (open it in a browser)");
    outln!("serving {} tileset(s) on http://{addr}  (Ctrl-C to stop)", names.len());
    outln!("  http://{addr}/tilesets");
    for n in names.iter().take(3) {
        outln!(
            "  http://{addr}/tilesets/{n}/3dtiles/tileset.json   (OGC 3D Tiles 1.1: CesiumJS, Unreal, Unity, three.js)"
        );
        outln!("  http://{addr}/tilesets/{n}/tileset.json");
        outln!("  http://{addr}/tilesets/{n}/index/0/0/0.json");
        outln!("  http://{addr}/tilesets/{n}/tiles/0/0/0/0");
    }
    outln!("  http://{addr}/openapi.json   http://{addr}/metrics   http://{addr}/readyz");
}
