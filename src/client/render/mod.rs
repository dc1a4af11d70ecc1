//! The client's headless wgpu renderer: tile meshes (with crack-hiding skirts) shaded by their
//! normals, point levels as instanced oriented splats sized by the level's point spacing,
//! into an offscreen colour + depth target read back as an RGBA image (PNG with
//! [`Renderer::save_png`]). Each (tile, level) is uploaded once into its own GPU buffers (the
//! third paper) and drawn from there every frame until [`Renderer::evict`].
//!
//! Positions are uploaded relative to an origin (the tileset's lower corner) so f32 keeps
//! centimetres on tilesets hundreds of kilometres wide. The device and queue are passed in.

use std::collections::HashMap;
use std::path::Path;
use std::sync::mpsc;

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use glam::dcamera::rh;

use crate::client::select::{Camera, DrawItem, add_skirts};
use crate::client::tree::TileTree;
use crate::codec::{Blob, Geometry};
use crate::geom::{Bounds, Mesh};
use crate::gpu::GpuError;
use crate::store::Manifest;
use crate::tiling::TileKey;

/// The pipelines' WGSL (name, source), for validation without an adapter.
pub const SHADERS: [(&str, &str); 2] = [
    (
        "render_mesh",
        concat!(
            include_str!("../../../shaders/render/common.wgsl"),
            include_str!("../../../shaders/render/mesh.wgsl")
        ),
    ),
    (
        "render_points",
        concat!(
            include_str!("../../../shaders/render/common.wgsl"),
            include_str!("../../../shaders/render/splat.wgsl"),
            include_str!("../../../shaders/render/points.wgsl")
        ),
    ),
];

const COLOR: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Background colour (RGBA8): pure black, which no shaded surface reaches (ambient floor).
pub const BACKGROUND: [u8; 4] = [0, 0, 0, 255];

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Globals {
    view_proj: [[f32; 4]; 4],
    light: [f32; 4],
    viewport: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TileUniform {
    /// A point level's cell edge (world units) and footprint half-width (cells).
    spacing: f32,
    half: f32,
    pad: [f32; 2],
    /// The dataset's horizontal extent relative to the origin (min x, min y, max x, max y):
    /// splats are clipped to it (terrain does not go on past its raster).
    extent: [f32; 4],
}

/// Per-draw fade state (group 2, one slot per draw at a dynamic offset).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DrawUniform {
    alpha: f32,
    retiring: f32,
    pad: [f32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Vertex {
    p: [f32; 3],
    n: [f32; 3],
}

struct GpuTile {
    vertices: wgpu::Buffer,
    indices: Option<wgpu::Buffer>,
    count: u32,
    bind: wgpu::BindGroup,
    bytes: u64,
}

/// A headless renderer of one viewport size.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    width: u32,
    height: u32,
    origin: DVec3,
    mesh: wgpu::RenderPipeline,
    points: wgpu::RenderPipeline,
    globals: wgpu::Buffer,
    globals_bind: wgpu::BindGroup,
    tile_layout: wgpu::BindGroupLayout,
    draw_layout: wgpu::BindGroupLayout,
    draw_stride: u64,
    color: wgpu::Texture,
    depth: wgpu::Texture,
    tiles: HashMap<(TileKey, u8), GpuTile>,
}

/// wgpu's error `e` while doing `during`.
fn wgpu_err(during: &str, e: impl std::fmt::Display) -> GpuError {
    GpuError::Wgpu { during: during.into(), message: e.to_string() }
}

impl Renderer {
    /// Builds the pipelines and targets. `origin` is subtracted from every position uploaded.
    pub fn new(
        device: wgpu::Device,
        queue: wgpu::Queue,
        width: u32,
        height: u32,
        origin: DVec3,
    ) -> Result<Self, GpuError> {
        let max = device.limits().max_texture_dimension_2d;
        if width == 0 || height == 0 || width > max || height > max {
            return Err(GpuError::Viewport { stage: "render", width, height, max });
        }
        let uniform = |binding, visibility, has_dynamic_offset| wgpu::BindGroupLayoutEntry {
            binding,
            visibility,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset,
                min_binding_size: None,
            },
            count: None,
        };
        let vf = wgpu::ShaderStages::VERTEX_FRAGMENT;
        let globals_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render globals"),
            entries: &[uniform(0, vf, false)],
        });
        let tile_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render tile"),
            entries: &[uniform(0, vf, false)],
        });
        let draw_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render draw"),
            entries: &[uniform(0, wgpu::ShaderStages::FRAGMENT, true)],
        });
        let draw_stride = (std::mem::size_of::<DrawUniform>() as u64)
            .next_multiple_of(u64::from(device.limits().min_uniform_buffer_offset_alignment.max(1)));
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("render"),
            bind_group_layouts: &[Some(&globals_layout), Some(&tile_layout), Some(&draw_layout)],
            immediate_size: 0,
        });
        let attrs = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3];
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let make = |(name, src): (&str, &str), step: wgpu::VertexStepMode| {
            let module = crate::gpu::shader_module(&device, name, src);
            let buffers = [Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<Vertex>() as u64,
                step_mode: step,
                attributes: &attrs,
            })];
            // No culling: skirts and TIN winding are both seen from either side.
            crate::gpu::opaque_pipeline(&device, name, &layout, &module, "vs_main", &buffers, (COLOR, DEPTH))
        };
        let mesh = make(SHADERS[0], wgpu::VertexStepMode::Vertex);
        let points = make(SHADERS[1], wgpu::VertexStepMode::Instance);
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("render globals"),
            size: std::mem::size_of::<Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let globals_bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("render globals"),
            layout: &globals_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: globals.as_entire_binding() }],
        });
        let target = |format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some("render target"),
                size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let color = target(COLOR, wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC);
        // COPY_SRC: `render_with_depth` reads the depth back (the evaluation's depth differences).
        let depth = target(DEPTH, wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(wgpu_err("render: pipeline creation", e));
        }
        Ok(Self {
            device,
            queue,
            width,
            height,
            origin,
            mesh,
            points,
            globals,
            globals_bind,
            tile_layout,
            draw_layout,
            draw_stride,
            color,
            depth,
            tiles: HashMap::new(),
        })
    }

    /// True when the (tile, level) is on the GPU.
    #[must_use]
    pub fn has(&self, key: TileKey, level: u8) -> bool {
        self.tiles.contains_key(&(key, level))
    }

    /// GPU bytes held by uploaded tiles.
    #[must_use]
    pub fn gpu_bytes(&self) -> u64 {
        self.tiles.values().map(|t| t.bytes).sum()
    }

    /// Uploads a decoded blob once: a mesh with skirts `skirt_depth` deep (none on the dataset's
    /// `outer` border), or points drawn as footprints for a level of cell edge `point_spacing`
    /// (world units) and footprint half-width `footprint_half` (cells; see [`footprint_half`]),
    /// clipped horizontally to `outer`.
    pub fn upload(
        &mut self,
        blob: &Blob,
        skirt_depth: f64,
        outer: Option<&Bounds>,
        point_spacing: f64,
        footprint_half: f64,
    ) {
        let key = (blob.header.key, blob.header.level);
        if self.tiles.contains_key(&key) {
            return;
        }
        let o = self.origin;
        let rel = |p: [f64; 3]| [(p[0] - o[0]) as f32, (p[1] - o[1]) as f32, (p[2] - o[2]) as f32];
        let (vertices, indices): (Vec<Vertex>, Option<Vec<u32>>) = match &blob.geometry {
            Geometry::Mesh(m) => {
                let sk = add_skirts(m, skirt_depth, outer);
                let normals = skirted_normals(&sk.mesh, sk.first_skirt_vertex, sk.first_skirt_triangle);
                let v = sk
                    .mesh
                    .positions
                    .iter()
                    .zip(&normals)
                    .map(|(p, n)| Vertex { p: rel(*p), n: *n })
                    .collect();
                (v, Some(sk.mesh.triangles.iter().flatten().copied().collect()))
            }
            Geometry::Points(pc) => {
                let v = pc
                    .positions
                    .iter()
                    .zip(pc.normals.iter().chain(std::iter::repeat(&[0.0, 0.0, 1.0])))
                    .map(|(p, n)| Vertex { p: rel(*p), n: *n })
                    .collect();
                (v, None)
            }
        };
        let buf = |label, contents: &[u8], usage| {
            let b = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: (contents.len() as u64).max(4).next_multiple_of(4),
                usage: usage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            if !contents.is_empty() {
                self.queue.write_buffer(&b, 0, contents);
            }
            b
        };
        let vb = buf("tile vertices", bytemuck::cast_slice(&vertices), wgpu::BufferUsages::VERTEX);
        let ib =
            indices.as_ref().map(|i| buf("tile indices", bytemuck::cast_slice(i), wgpu::BufferUsages::INDEX));
        let extent = outer.map_or([f32::MIN, f32::MIN, f32::MAX, f32::MAX], |b| {
            let (lo, hi) = (rel(b.min.to_array()), rel(b.max.to_array()));
            [lo[0], lo[1], hi[0], hi[1]]
        });
        let u =
            TileUniform { spacing: point_spacing as f32, half: footprint_half as f32, pad: [0.0; 2], extent };
        let ub = buf("tile uniform", bytemuck::bytes_of(&u), wgpu::BufferUsages::UNIFORM);
        let bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("render tile"),
            layout: &self.tile_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: ub.as_entire_binding() }],
        });
        let count = indices.as_ref().map_or(vertices.len(), Vec::len) as u32;
        let bytes = vb.size() + ib.as_ref().map_or(0, wgpu::Buffer::size);
        self.tiles.insert(key, GpuTile { vertices: vb, indices: ib, count, bind, bytes });
    }

    /// Frees a tile's GPU buffers.
    pub fn evict(&mut self, key: TileKey, level: u8) {
        self.tiles.remove(&(key, level));
    }

    /// Draws the items that are uploaded and reads the frame back (RGBA8, rows top to bottom).
    /// Fading items (`alpha < 1`, or `retiring`) are drawn with complementary ordered-dither
    /// masks (see [`DrawItem::retiring`]); items not uploaded are skipped. `far` is the
    /// far-plane distance (the whole dataset must fit in it).
    pub fn render(
        &self,
        camera: &Camera,
        draws: &[DrawItem],
        far: f64,
    ) -> Result<image::RgbaImage, GpuError> {
        let (near, far) = clip_planes(far);
        Ok(self
            .frame(camera, draws, near, far, true, false)?
            .ok_or(GpuError::Internal("render: no read-back"))?
            .0)
    }

    /// As [`Renderer::render`] with explicit clip planes (`0 < near < far`; a near plane close
    /// to the geometry keeps the depth precise), plus the depth buffer: row-major, rows top to
    /// bottom, `[0, 1]` (`depth = far·(D − near) / ((far − near)·D)` for view depth `D`), 1
    /// where nothing was drawn.
    pub fn render_with_depth(
        &self,
        camera: &Camera,
        draws: &[DrawItem],
        near: f64,
        far: f64,
    ) -> Result<(image::RgbaImage, Vec<f32>), GpuError> {
        if !(near.is_finite() && far.is_finite() && near > 0.0 && near < far) {
            return Err(GpuError::ClipPlanes { near, far });
        }
        self.frame(camera, draws, near, far, true, true)?.ok_or(GpuError::Internal("render: no read-back"))
    }

    /// As [`Renderer::render`] and waits for the GPU to finish, without reading the frame back
    /// (frames that are timed but not written).
    pub fn draw(&self, camera: &Camera, draws: &[DrawItem], far: f64) -> Result<(), GpuError> {
        let (near, far) = clip_planes(far);
        self.frame(camera, draws, near, far, false, false).map(|_| ())
    }

    fn frame(
        &self,
        camera: &Camera,
        draws: &[DrawItem],
        near: f64,
        far: f64,
        read_back: bool,
        with_depth: bool,
    ) -> Result<Option<(image::RgbaImage, Vec<f32>)>, GpuError> {
        let view = camera.view().map_err(|e| GpuError::Camera { stage: "render", message: e.to_string() })?;
        let vp = view_proj(&view, self.origin, near, far, f64::from(self.width) / f64::from(self.height));
        let g = Globals {
            view_proj: vp,
            light: [0.4, 0.3, 0.86, 0.0],
            viewport: [self.width as f32, self.height as f32, view.k as f32, 0.0],
        };
        self.queue.write_buffer(&self.globals, 0, bytemuck::bytes_of(&g));
        // What is drawn, with each draw's fade state in its own slot of one per-frame buffer.
        let list: Vec<(&GpuTile, DrawUniform)> = draws
            .iter()
            .filter(|d| d.alpha > 0.0)
            .filter_map(|d| {
                let t = self.tiles.get(&(d.key, d.level)).filter(|t| t.count > 0)?;
                let u = DrawUniform {
                    alpha: d.alpha.min(1.0),
                    retiring: if d.retiring { 1.0 } else { 0.0 },
                    pad: [0.0; 2],
                };
                Some((t, u))
            })
            .collect();
        let stride = self.draw_stride as usize;
        let mut slots = vec![0u8; (list.len().max(1)) * stride];
        for (i, (_, u)) in list.iter().enumerate() {
            slots[i * stride..i * stride + std::mem::size_of::<DrawUniform>()]
                .copy_from_slice(bytemuck::bytes_of(u));
        }
        let draw_buf = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("render draws"),
            size: slots.len() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.queue.write_buffer(&draw_buf, 0, &slots);
        let draw_bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("render draws"),
            layout: &self.draw_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &draw_buf,
                    offset: 0,
                    size: wgpu::BufferSize::new(std::mem::size_of::<DrawUniform>() as u64),
                }),
            }],
        });
        let cview = self.color.create_view(&wgpu::TextureViewDescriptor::default());
        let dview = self.depth.create_view(&wgpu::TextureViewDescriptor::default());
        let mut enc =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("render") });
        {
            let bg = wgpu::Color {
                r: f64::from(BACKGROUND[0]) / 255.0,
                g: f64::from(BACKGROUND[1]) / 255.0,
                b: f64::from(BACKGROUND[2]) / 255.0,
                a: 1.0,
            };
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("render"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &cview,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: wgpu::LoadOp::Clear(bg), store: wgpu::StoreOp::Store },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &dview,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_bind_group(0, &self.globals_bind, &[]);
            for (i, (t, _)) in list.iter().enumerate() {
                pass.set_bind_group(1, &t.bind, &[]);
                pass.set_bind_group(2, &draw_bind, &[(i * stride) as u32]);
                pass.set_vertex_buffer(0, t.vertices.slice(..));
                if let Some(ib) = &t.indices {
                    pass.set_pipeline(&self.mesh);
                    pass.set_index_buffer(ib.slice(..), wgpu::IndexFormat::Uint32);
                    pass.draw_indexed(0..t.count, 0, 0..1);
                } else {
                    pass.set_pipeline(&self.points);
                    pass.draw(0..6, 0..t.count);
                }
            }
        }
        if !read_back {
            self.queue.submit([enc.finish()]);
            self.device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| wgpu_err("render: waiting for the device", e))?;
            return Ok(None);
        }
        let row = (self.width * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("render read-back"),
            size: u64::from(row) * u64::from(self.height),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &self.color,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &staging,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: Some(self.height),
                },
            },
            wgpu::Extent3d { width: self.width, height: self.height, depth_or_array_layers: 1 },
        );
        let depth_staging = with_depth.then(|| {
            let b = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("render depth read-back"),
                size: u64::from(row) * u64::from(self.height),
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            });
            enc.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: &self.depth,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::DepthOnly,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &b,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(row),
                        rows_per_image: Some(self.height),
                    },
                },
                wgpu::Extent3d { width: self.width, height: self.height, depth_or_array_layers: 1 },
            );
            b
        });
        self.queue.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        let tx2 = tx.clone();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        if let Some(b) = &depth_staging {
            b.slice(..).map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx2.send(r);
            });
        } else {
            drop(tx2);
        }
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| wgpu_err("render: waiting for the device", e))?;
        for _ in 0..=usize::from(depth_staging.is_some()) {
            rx.recv()
                .map_err(|_| GpuError::Internal("render: read-back callback dropped"))?
                .map_err(|e| wgpu_err("render: read-back", e))?;
        }
        let data = staging.slice(..).get_mapped_range().map_err(|e| wgpu_err("render: mapping", e))?;
        let mut px = Vec::with_capacity((self.width * self.height * 4) as usize);
        for r in 0..self.height as usize {
            let s = r * row as usize;
            px.extend_from_slice(&data[s..s + self.width as usize * 4]);
        }
        drop(data);
        let mut depth = Vec::new();
        if let Some(b) = &depth_staging {
            let data = b.slice(..).get_mapped_range().map_err(|e| wgpu_err("render: mapping", e))?;
            depth.reserve((self.width * self.height) as usize);
            for r in 0..self.height as usize {
                let s = r * row as usize;
                let bytes = &data[s..s + self.width as usize * 4];
                depth.extend(bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])));
            }
        }
        let img = image::RgbaImage::from_raw(self.width, self.height, px)
            .ok_or(GpuError::Internal("render: image size"))?;
        Ok(Some((img, depth)))
    }

    /// Writes a frame as PNG.
    pub fn save_png(img: &image::RgbaImage, path: &Path) -> Result<(), crate::client::ClientError> {
        img.save_with_format(path, image::ImageFormat::Png)
            .map_err(|source| crate::client::ClientError::Png { path: path.to_owned(), source })
    }
}

/// World-space point spacing of `level` at node `key` (the splat size): a terrain level's
/// slicing cell (`cell_leaf_cells` leaf cells, scaled by the node's sample step); else, for a
/// model level, the node's largest extent over the level's texture size; 0 for a mesh level or
/// when unknown (splats are then one pixel).
#[must_use]
pub fn point_spacing(manifest: &Manifest, tree: &TileTree, key: TileKey, level: u8) -> f64 {
    let Some(spec) = manifest.levels.get(usize::from(level)) else { return 0.0 };
    if spec.kind != crate::codec::Kind::Points {
        return 0.0;
    }
    let cell = manifest.frame.dx.abs().max(manifest.frame.dy.abs());
    if let (Some(c), true) = (spec.cell_leaf_cells, cell > 0.0) {
        return f64::from(c) * f64::from(tree.pyramid().step(key.z)) * cell;
    }
    match (spec.texture_size, tree.find(key)) {
        (Some(t), Some(n)) if t > 0 => {
            let s = tree.node(n).bounds.size();
            s[0].abs().max(s[1].abs()).max(s[2].abs()) / f64::from(t)
        }
        _ => 0.0,
    }
}

/// Footprint half-width (cells) of point `level`: the manifest's `footprint_half`, or for a
/// tileset baked before it was recorded the kind's default (terrain levels have a
/// `cell_leaf_cells`); 0 for a mesh level.
#[must_use]
pub fn footprint_half(manifest: &Manifest, level: u8) -> f64 {
    match manifest.levels.get(usize::from(level)) {
        Some(spec) if spec.kind == crate::codec::Kind::Points => {
            spec.footprint_half.unwrap_or(if spec.cell_leaf_cells.is_some() {
                crate::lod::TERRAIN_FOOTPRINT_HALF
            } else {
                crate::lod::MODEL_FOOTPRINT_HALF
            })
        }
        _ => 0.0,
    }
}

/// Pixels of `img` that are not the background.
#[must_use]
pub fn covered(img: &image::RgbaImage) -> Vec<bool> {
    img.pixels().map(|p| p.0 != BACKGROUND).collect()
}

/// Area-weighted vertex normals of the surface triangles; a skirt vertex takes the normal of
/// the border vertex above it (same x, y) so the wall reads as the surface.
fn skirted_normals(m: &Mesh, first_skirt_vertex: usize, first_skirt_triangle: usize) -> Vec<[f32; 3]> {
    let surface = &m.triangles[..first_skirt_triangle.min(m.triangles.len())];
    let mut acc = crate::geom::vertex_normal_sums(&m.positions, surface);
    let key = |p: [f64; 3]| (p[0].to_bits(), p[1].to_bits());
    let above: HashMap<(u64, u64), usize> =
        m.positions[..first_skirt_vertex].iter().enumerate().map(|(i, p)| (key(*p), i)).collect();
    for i in first_skirt_vertex..m.positions.len() {
        if let Some(&j) = above.get(&key(m.positions[i])) {
            acc[i] = acc[j];
        }
    }
    acc.into_iter().map(|n| crate::geom::unit_f32(n).unwrap_or([0.0, 0.0, 1.0])).collect()
}

/// Near and far plane distances the renderers use for a far distance `far`.
#[must_use]
pub fn clip_planes(far: f64) -> (f64, f64) {
    let far = far.max(1e-3);
    ((far * 1e-5).max(1e-3).min(far * 0.5), far)
}

/// Column-major view-projection (wgpu: depth 0..1 and y up in NDC, as Direct3D's) for
/// positions relative to `origin`: glam's right-handed look-to and perspective, the vertical field of view derived from the
/// camera's horizontal one and `aspect` (width / height).
pub(crate) fn view_proj(
    v: &crate::client::select::View,
    origin: DVec3,
    near: f64,
    far: f64,
    aspect: f64,
) -> [[f32; 4]; 4] {
    let eye = v.eye - origin;
    let view = rh::view::look_to_mat4(eye, v.forward, v.up);
    let fov_y = 2.0 * (v.tan_h / aspect).atan();
    (rh::proj::directx::perspective(fov_y, aspect, near, far) * view).as_mat4().to_cols_array_2d()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shaders_validate_with_naga() {
        for (name, src) in SHADERS {
            let module = naga::front::wgsl::parse_str(src).map_err(|e| e.emit_to_string(src)).unwrap();
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::empty(),
            )
            .validate(&module)
            .map_err(|e| format!("{name}: {}", e.emit_to_string(src)))
            .unwrap();
        }
    }

    #[test]
    fn projection_maps_target_to_centre() {
        let cam = Camera {
            eye: DVec3::new(100.0, 0.0, 50.0),
            target: DVec3::new(100.0, 100.0, 0.0),
            up: DVec3::Z,
            width: 200,
            height: 100,
            fov_deg: 60.0,
        };
        let v = cam.view().unwrap();
        let m = view_proj(&v, DVec3::new(100.0, 0.0, 0.0), 1.0, 1000.0, 2.0);
        let p = [0.0f32, 100.0, 0.0, 1.0];
        let clip: Vec<f32> = (0..4).map(|r| (0..4).map(|c| m[c][r] * p[c]).sum()).collect();
        assert!((clip[0] / clip[3]).abs() < 1e-5 && (clip[1] / clip[3]).abs() < 1e-5, "{clip:?}");
        assert!(clip[2] / clip[3] > 0.0 && clip[2] / clip[3] < 1.0);
    }
}
