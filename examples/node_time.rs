use std::time::Instant;
use terrastream::bake::{BakeOptions, bake_node_geometry};
use terrastream::raster::{self, LoadOptions, Overrides};
use terrastream::tiling::Pyramid;
fn main() -> anyhow::Result<()> {
    let p = std::env::args().nth(1).unwrap_or("../shared/data/fuji.png".into());
    let r = raster::load(
        p.as_ref(),
        &LoadOptions {
            encoding: Some(raster::Encoding::TerrainRgb),
            overrides: Overrides { cell_size: Some(30.0), ..Default::default() },
            ..Default::default()
        },
    )?;
    let py = Pyramid::new(r.heights.width, r.heights.height, 256)?;
    let opts = BakeOptions::default();
    for key in py.nodes() {
        let t = Instant::now();
        let (nb, _) = bake_node_geometry(&py, &r.heights, &r.georef, key, &opts)?;
        println!(
            "{key}: {:?} v={} err={:?} pts={:?}",
            t.elapsed(),
            nb.mesh.positions.len(),
            nb.mesh_errors,
            nb.points
                .iter()
                .map(|(p, e)| (
                    p.positions.len(),
                    (e.max * 100.0).round() / 100.0,
                    (e.gap * 100.0).round() / 100.0
                ))
                .collect::<Vec<_>>()
        );
    }
    Ok(())
}
