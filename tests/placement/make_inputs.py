#!/usr/bin/env python3
"""Writes the adversarial inputs of the placement checker and their manifest.

    make_inputs.py OUTDIR [--data DIR]

Every generated raster samples one synthetic relief defined on the sphere (a sum of sines of the
unit vector, so it is continuous across the antimeridian, at the poles and between UTM zones),
plus a little seeded noise. Files are small (at most 300 x 300 samples; the .hgt tile is
1201 x 1201 because that is what an SRTM tile is). `manifest.json` lists every input: its files,
its CRS (for the table), the vertical datum its heights are in, and the bake options it needs.
The real DEMs of DATA/geo (default: $TERRASTREAM_DATA or ../shared/data) are listed too.

Needs rasterio, pyproj and numpy (the CI venv). Deterministic: the same run writes the same files.
"""

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np
import rasterio
from pyproj import CRS, Transformer
from rasterio.transform import Affine

R_EARTH = 6_371_000.0
# Options every bake gets: small leaf tiles keep each TIN small; no point levels are needed to
# check placement (only the level-0 meshes are read); the CPU baker, so no GPU is probed.
COMMON_BAKE = ["--tile-size", "64", "--levels", "1", "--gpu", "off"]


def unit_vectors(lon, lat):
    lam, phi = np.radians(lon), np.radians(lat)
    return np.stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)], axis=-1)


def relief(lon, lat, *, wavelength_m, amplitude, base, seed, noise=0.2):
    """Smooth relief on the sphere: sum of sines of u.d_k (d_k fixed random directions).

    A sine of R*(u.d) changes at most one metre of argument per metre on the ground, so the
    shortest wavelength on the ground is the given one. `noise` adds seeded per-sample noise (m).
    """
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(6, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    scales = np.array([1.0, 0.61, 0.37, 0.23, 1.7, 0.83])
    amps = amplitude * np.array([1.0, 0.5, 0.3, 0.15, 0.6, 0.25])
    phases = rng.uniform(0, 2 * np.pi, 6)
    u = unit_vectors(lon, lat)
    h = np.full(np.shape(lon), float(base))
    for d, s, a, p in zip(dirs, scales, amps, phases):
        h += a * np.sin(2 * np.pi * R_EARTH * (u @ d) / (wavelength_m * s) + p)
    if noise:
        h += rng.normal(scale=noise, size=np.shape(lon))
    return h


def sample_lonlat(transform, crs, width, height):
    """Longitude/latitude (WGS 84) of every sample centre of a grid (rasterio's convention:
    the transform maps pixel corners, so centres are at col + 0.5, row + 0.5)."""
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    xs = transform.a * cols + transform.b * rows + transform.c
    ys = transform.d * cols + transform.e * rows + transform.f
    horiz = CRS.from_user_input(crs)
    if horiz.is_compound:
        horiz = horiz.sub_crs_list[0]
    if horiz.is_geographic and horiz.equals(CRS.from_epsg(4326)):
        return np.asarray(xs), np.asarray(ys)
    t = Transformer.from_crs(horiz, CRS.from_epsg(4326), always_xy=True)
    lon, lat = t.transform(xs, ys)
    return np.asarray(lon), np.asarray(lat)


def write_tif(path, data, transform, crs, nodata=None, units="metre", description=None):
    profile = dict(
        driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype=data.dtype.name,
        crs=crs, transform=transform, tiled=False, compress="deflate",
    )
    if nodata is not None:
        profile["nodata"] = nodata
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data, 1)
        dst.units = (units,)
        if description:
            dst.update_tags(TIFFTAG_IMAGEDESCRIPTION=description)


def grid_around(crs, lon, lat, cell, width, height):
    """A north-up transform in `crs` whose grid (width x height cells of `cell` CRS units) is
    centred on lon/lat (WGS 84)."""
    horiz = CRS.from_user_input(crs)
    if horiz.is_compound:
        horiz = horiz.sub_crs_list[0]
    x, y = Transformer.from_crs(CRS.from_epsg(4326), horiz, always_xy=True).transform(lon, lat)
    # Whole cells, so the grid is reproducible and easy to read in gdalinfo.
    x0 = round((x - cell * width / 2) / cell) * cell
    y0 = round((y + cell * height / 2) / cell) * cell
    return Affine(cell, 0, x0, 0, -cell, y0)


def synthetic(path, crs, transform, width, height, *, seed, wavelength_m, amplitude, base,
              nodata=None, nodata_cells=(), description=None):
    lon, lat = sample_lonlat(transform, crs, width, height)
    h = relief(lon, lat, wavelength_m=wavelength_m, amplitude=amplitude, base=base, seed=seed)
    data = h.astype(np.float32)
    for r, c in nodata_cells:
        data[r, c] = nodata
    write_tif(path, data, transform, crs, nodata=nodata, description=description)


def missing(path):
    """Shared data not found: an error where CI requires the data, else the input is left out."""
    if os.environ.get("TERRASTREAM_REQUIRE_DATA"):
        sys.exit(f"make_inputs.py: {path} not found (TERRASTREAM_REQUIRE_DATA is set)")
    print(f"warning: {path} not found: left out", file=sys.stderr)


def entry(name, files, crs, datum, bake=(), note="", **extra):
    return dict(name=name, files=[str(f) for f in files], crs=crs, datum=datum,
                bake_args=COMMON_BAKE + list(bake), note=note, **extra)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("outdir", type=Path)
    ap.add_argument("--data", type=Path,
                    default=Path(os.environ.get("TERRASTREAM_DATA", Path(__file__).resolve().parents[3] / "shared" / "data")))
    args = ap.parse_args()
    out: Path = args.outdir.resolve()
    out.mkdir(parents=True, exist_ok=True)
    data_dir: Path = args.data.resolve()
    inputs = []

    # 1. US survey feet horizontally, metres vertically, said by the GeoKeys: the compound CRS
    #    NAD83 / Texas North Central (ftUS) + EGM96 height writes VerticalCSTypeGeoKey 5773
    #    and VerticalUnitsGeoKey 9001 (metre); the band's unit is "metre" too.
    crs = "EPSG:2276+5773"
    t = grid_around(crs, -97.05, 32.85, 100.0, 240, 200)  # 100 ftUS = 30.48 m cells
    synthetic(out / "texas_ftus.tif", crs, t, 240, 200, seed=1, wavelength_m=4000, amplitude=40, base=180,
              description="heights in metres above the EGM96 geoid; horizontal unit US survey foot")
    inputs.append(entry("texas_ftus", [out / "texas_ftus.tif"], "EPSG:2276+5773 (ftUS)", "egm96",
                        note="cells 100 US survey feet; heights metres (VerticalUnitsGeoKey 9001), EGM96 (VerticalCSTypeGeoKey 5773)"))

    # 2. Web Mercator at 57 N: CRS units are 1.84x ground metres there. A few no-data cells.
    crs = "EPSG:3857"
    t = grid_around(crs, 10.4, 57.2, 40.0, 220, 200)
    holes = [(37, 51), (38, 51), (37, 52), (38, 52), (120, 150), (100, 17), (150, 200), (9, 110)]
    synthetic(out / "webmerc_57n.tif", crs, t, 220, 200, seed=2, wavelength_m=3000, amplitude=60, base=60,
              nodata=-9999.0, nodata_cells=holes)
    inputs.append(entry("webmerc_57n", [out / "webmerc_57n.tif"], "EPSG:3857", "ellipsoid",
                        note="40 m Web Mercator cells (21.7 m on the ground); 8 no-data cells (-9999)"))

    # 3. Geographic, longitudes written 170..190 (0-360 convention).
    crs = "EPSG:4326"
    t = Affine(0.08, 0, 170.0, 0, -0.08, -38.0)
    synthetic(out / "lon0360.tif", crs, t, 250, 50, seed=3, wavelength_m=300_000, amplitude=700, base=500)
    inputs.append(entry("lon0360", [out / "lon0360.tif"], "EPSG:4326 (lon 170..190)", "ellipsoid",
                        note="longitudes written past 180 (0-360 convention), 0.08 deg cells, 38-42 S"))

    # 4. Across the antimeridian, -180..180 convention: two files side by side on the ground,
    #    179.5..180 E and -180..-179.5.
    t_w = Affine(0.005, 0, 179.5, 0, -0.005, 66.0)
    t_e = Affine(0.005, 0, -180.0, 0, -0.005, 66.0)
    synthetic(out / "antimeridian_w.tif", crs, t_w, 100, 200, seed=4, wavelength_m=20_000, amplitude=150, base=200)
    synthetic(out / "antimeridian_e.tif", crs, t_e, 100, 200, seed=4, wavelength_m=20_000, amplitude=150, base=200)
    inputs.append(entry("antimeridian", [out / "antimeridian_w.tif", out / "antimeridian_e.tif"],
                        "EPSG:4326 (2 files)", "ellipsoid",
                        note="179.5E..180 and -180..-179.5 at 65-66 N, 0.005 deg cells, one dataset of two files"))

    # 5. North polar cap in EPSG:4326: the top row of sample centres is at 90 N (its cells reach
    #    past 90), longitudes all round.
    t = Affine(1.2, 0, -180.0, 0, -0.01, 90.005)
    synthetic(out / "northcap_4326.tif", crs, t, 300, 201, seed=5, wavelength_m=60_000, amplitude=200, base=300)
    inputs.append(entry("northcap_4326", [out / "northcap_4326.tif"], "EPSG:4326 (88-90 N)", "ellipsoid",
                        note="1.2 x 0.01 deg cells, top sample row at 90 N (cells past 90), all longitudes"))

    # 6. South polar cap in Antarctic Polar Stereographic: the pole is the centre sample.
    crs = "EPSG:3031"
    t = Affine(1000.0, 0, -100_500.0, 0, -1000.0, 100_500.0)
    synthetic(out / "southpole_3031.tif", crs, t, 201, 201, seed=6, wavelength_m=40_000, amplitude=300, base=2800)
    inputs.append(entry("southpole_3031", [out / "southpole_3031.tif"], "EPSG:3031", "ellipsoid",
                        note="1 km cells, 201 x 201, the South Pole is sample (100, 100)"))

    # 7. Three UTM zones along 48 N, near 12 E: each file in its own zone's CRS (31N far from its
    #    central meridian), 150 x 150 cells of 30 m (4.5 km), centres 3.7 km apart: each overlaps
    #    its neighbour by 250 m or more on the ground (their grids are rotated against each other
    #    by the grid convergence, 2.2 to 6.6 degrees here, so a narrower overlap leaves gaps).
    files = []
    for zone, lon in [(31, 11.95), (32, 12.0), (33, 12.05)]:
        crs = f"EPSG:326{zone}"
        t = grid_around(crs, lon, 48.0, 30.0, 150, 150)
        f = out / f"utm{zone}n_48n.tif"
        synthetic(f, crs, t, 150, 150, seed=7, wavelength_m=3000, amplitude=80, base=500)
        files.append(f)
    inputs.append(entry("utm_3zones", files, "EPSG:32631/32632/32633", "ellipsoid", warped=True,
                        note="three files, one per UTM zone, adjacent along 48 N: a mosaic that must be warped"))

    # 8. fuji.png (terrain-RGB) given a CRS by a VRT: JGD2011 / Japan Plane Rectangular CS IX
    #    (EPSG:6677, whose EPSG axis order is northing, easting; a GDAL GeoTransform is always
    #    easting, northing), 10 m cells, centred on the summit.
    fuji = data_dir / "fuji.png"
    if fuji.exists():
        x, y = Transformer.from_crs(CRS.from_epsg(4326), CRS.from_epsg(6677), always_xy=True).transform(138.7274, 35.3606)
        x0, y0 = round(x - 2560.0), round(y + 2560.0)
        vrt = f"""<VRTDataset rasterXSize="512" rasterYSize="512">
  <SRS>EPSG:6677</SRS>
  <GeoTransform>{x0:.1f}, 10.0, 0.0, {y0:.1f}, 0.0, -10.0</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">
    <SimpleSource>
      <SourceFilename relativeToVRT="0">{fuji}</SourceFilename>
      <SourceBand>1</SourceBand>
      <SrcRect xOff="0" yOff="0" xSize="512" ySize="512"/>
      <DstRect xOff="0" yOff="0" xSize="512" ySize="512"/>
    </SimpleSource>
  </VRTRasterBand>
</VRTDataset>
"""
        (out / "fuji_6677.vrt").write_text(vrt)
        inputs.append(entry("fuji_6677", [out / "fuji_6677.vrt"], "EPSG:6677 (VRT)", "egm96",
                            bake=["--encoding", "terrain-rgb", "--vertical-datum", "egm96"],
                            heights={"terrain_rgb": str(fuji)},
                            note="fuji.png decoded as terrain-RGB; georeference from the VRT; heights above sea level"))
    else:
        missing(fuji)

    # 9. An SRTM-like 1 degree tile: 1201 x 1201 big-endian int16, EGM96 heights, a coast (sea
    #    at 0) in the west.
    hgt_dir = out / "hgt"
    hgt_dir.mkdir(exist_ok=True)
    n = 1201
    lat = 58.0 - np.arange(n)[:, None] / 1200.0 * np.ones((1, n))
    lon = 6.0 + np.ones((n, 1)) * np.arange(n)[None, :] / 1200.0
    h = relief(lon, lat, wavelength_m=8000, amplitude=120, base=0, seed=9, noise=0.0)
    h += (lon - 6.35) * 1500.0 + 60.0 * np.sin(lat * 40.0)
    h = np.where(h < 0, 0.0, h)
    np.round(h).astype(">i2").tofile(hgt_dir / "N57E006.hgt")
    inputs.append(entry("srtm_n57e006", [hgt_dir / "N57E006.hgt"], "EPSG:4326 (.hgt)", "egm96",
                        note="synthetic 3-arc-second tile, sea (0 m) in the west; .hgt heights are EGM96"))

    # 9b. A 3 x 3 degree mosaic of nine such tiles (N56..N58, E005..E007): one continuous surface,
    #     so the rows and columns the tiles share hold the same heights.
    files = []
    for south in (56, 57, 58):
        for west in (5, 6, 7):
            lat = (south + 1.0) - np.arange(n)[:, None] / 1200.0 * np.ones((1, n))
            lon = west + np.ones((n, 1)) * np.arange(n)[None, :] / 1200.0
            h = relief(lon, lat, wavelength_m=9000, amplitude=150, base=200, seed=11, noise=0.0)
            h += 80.0 * np.sin(lon * 3.0) * np.cos(lat * 2.0)
            f = hgt_dir / f"N{south:02d}E{west:03d}.hgt"
            if f.name == "N57E006.hgt":
                f = out / "hgt9" / f.name
            f.parent.mkdir(exist_ok=True)
            np.round(h).astype(">i2").tofile(f)
            files.append(f)
    inputs.append(entry("srtm_3x3_mosaic", files, "EPSG:4326 (9 .hgt)", "egm96",
                        note="nine 3-arc-second tiles, 3 x 3 degrees at 56-59 N; .hgt heights are EGM96"))

    # 9c. More projected CRSs: UTM 16N and 17S (southern hemisphere), Swiss LV95 (CH1903+, a
    #     7-parameter datum shift), New Zealand TM 2000 (NZGD2000).
    for k, (name, crs, lon, lat) in enumerate([("utm16n", "EPSG:32616", -87.5, 41.8),
                                             ("utm17s", "EPSG:32717", -79.0, -2.2),
                                             ("lv95", "EPSG:2056", 7.6, 46.5),
                                             ("nztm", "EPSG:2193", 172.6, -43.5)]):
        t = grid_around(crs, lon, lat, 25.0, 160, 140)
        f = out / f"{name}.tif"
        synthetic(f, crs, t, 160, 140, seed=20 + k, wavelength_m=2500, amplitude=150, base=300)
        inputs.append(entry(name, [f], crs, "ellipsoid", note=f"a generated 160 x 140 raster of 25 m cells in {crs}"))

    # 10. A vertical CRS terrastream does not support (NAVD88 height, VerticalCSTypeGeoKey 5703):
    #     must be refused, naming the key value; never taken for ellipsoidal heights.
    crs = "EPSG:26914+5703"
    t = grid_around(crs, -99.0, 35.0, 30.0, 64, 64)
    synthetic(out / "navd88_refused.tif", crs, t, 64, 64, seed=10, wavelength_m=2000, amplitude=20, base=400)
    inputs.append(entry("navd88_refused", [out / "navd88_refused.tif"], "EPSG:26914+5703", "navd88",
                        expect_refusal={"contains": ["5703"]},
                        note="NAVD88 heights (no grid for them here): the bake must refuse, naming 5703"))

    # The real DEMs (see DATA/geo/README.md).
    geo = data_dir / "geo"
    real = [
        ("nad83_utm18n", "nad83_utm18n_dem.tif", "EPSG:26918", "ellipsoid", [],
         "NAD83 / UTM 18N, 90 m; no vertical key, so heights are taken as ellipsoidal (the default)"),
        ("utm32n_vinschgau", "utm32n_vinschgau.tif", "EPSG:32632", "ellipsoid", [],
         "UTM 32N Alps, 250 m; no vertical key (default: ellipsoidal)"),
        ("utm32n_pixelispoint", "utm32n_pixelispoint_n00e010.tif", "EPSG:32632", "egm96",
         ["--vertical-datum", "egm96"], "UTM 32N at the equator, PixelIsPoint, SRTM (EGM96)"),
        ("etopo1_global", "etopo1_global_1deg.tif", "EPSG:4326 (global)", "egm96",
         ["--vertical-datum", "egm96"], "the whole globe at 1 deg, sample centres on +-90 and +-180; sea level = EGM96"),
    ]
    for name, file, crs, datum, bake, note in real:
        if (geo / file).exists():
            inputs.append(entry(name, [geo / file], crs, datum, bake=bake, note=note))
        else:
            missing(geo / file)

    manifest = {
        "about": "inputs of tests/placement/check.py; written by make_inputs.py",
        "geoid": "/usr/share/proj/egm96_15.gtx",
        "inputs": inputs,
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    print(f"{len(inputs)} inputs written to {out} (manifest.json)")


if __name__ == "__main__":
    main()
