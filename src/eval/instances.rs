//! The first paper's rendering experiment (its Tables 4–7): N×N instances of one baked model
//! drawn with and without LOD on this machine's adapter, timed frame by frame.
//!
//! Each level of the model is uploaded once (the mesh as vertex and index buffers, point levels
//! as storage buffers pulled by the vertex shader, six vertices per point forming a quad sized
//! by the level's point spacing, as the client's renderer draws them) and the instances' offsets
//! live in one storage buffer sorted by level, so a frame is one draw per level: without LOD,
//! one instanced draw of the mesh for every instance; with LOD, each level's instance range.
//! The device and queue are passed in; a frame is timed from encoding to the queue's completion
//! (no read-back).

use std::time::Instant;

use bytemuck::{Pod, Zeroable};

use crate::client::render::{clip_planes, view_proj};
use crate::client::select::Camera;
use crate::codec::{Blob, Geometry};
use crate::gpu::GpuError;

/// The pipeline's WGSL, for validation without an adapter.
pub const SHADER: &str = concat!(
    include_str!("../../shaders/render/splat.wgsl"),
    include_str!("../../shaders/render/instances.wgsl")
);

const COLOR: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Globals {
    view_proj: [[f32; 4]; 4],
    light: [f32; 4],
    viewport: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Vertex {
    p: [f32; 3],
    n: [f32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Point {
    p: [f32; 4],
    n: [f32; 4],
}

enum GpuLevel {
    Mesh { vertices: wgpu::Buffer, indices: wgpu::Buffer, count: u32 },
    Points { bind: wgpu::BindGroup, count: u32 },
}

/// One model's levels on the GPU and the targets to draw them into.
pub struct InstanceBench {
    device: wgpu::Device,
    queue: wgpu::Queue,
    width: u32,
    height: u32,
    origin: glam::DVec3,
    mesh: wgpu::RenderPipeline,
    points: wgpu::RenderPipeline,
    globals: wgpu::Buffer,
    globals_layout: wgpu::BindGroupLayout,
    levels: Vec<GpuLevel>,
    color: wgpu::TextureView,
    depth: wgpu::TextureView,
}

/// wgpu's error `e` while doing `during`.
fn wgpu_err(during: &str, e: impl std::fmt::Display) -> GpuError {
    GpuError::Wgpu { during: during.into(), message: e.to_string() }
}

/// What one frame drew.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FrameCounts {
    pub per_level: Vec<u32>,
    pub triangles: u64,
    pub points: u64,
}

impl InstanceBench {
    /// Uploads the model's levels (`levels[l]` with its point spacing in world units and its
    /// footprint half-width in cells; level 0
    /// must be the mesh). Positions are uploaded relative to `origin`.
    pub fn new(
        device: wgpu::Device,
        queue: wgpu::Queue,
        width: u32,
        height: u32,
        origin: glam::DVec3,
        levels: &[(Blob, f64, f64)],
    ) -> Result<Self, GpuError> {
        let max = device.limits().max_texture_dimension_2d;
        if width == 0 || height == 0 || width > max || height > max {
            return Err(GpuError::Viewport { stage: "instances", width, height, max });
        }
        if !matches!(levels.first(), Some((Blob { geometry: Geometry::Mesh(_), .. }, _, _))) {
            return Err(GpuError::NotAMesh);
        }
        let entry = |binding, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
            ty,
            count: None,
        };
        let uniform = wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        };
        let storage = wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        };
        let globals_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("instances globals"),
            entries: &[entry(0, uniform), entry(1, storage)],
        });
        let level_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("instances level"),
            entries: &[entry(0, storage), entry(1, uniform)],
        });
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = crate::gpu::shader_module(&device, "eval_instances", SHADER);
        let attrs = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3];
        let make = |entry: &str, layouts: &[Option<&wgpu::BindGroupLayout>], mesh: bool| {
            let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(entry),
                bind_group_layouts: layouts,
                immediate_size: 0,
            });
            let buffers = [Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<Vertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &attrs,
            })];
            crate::gpu::opaque_pipeline(
                &device,
                entry,
                &layout,
                &module,
                entry,
                if mesh { &buffers } else { &[] },
                (COLOR, DEPTH),
            )
        };
        let mesh = make("vs_mesh", &[Some(&globals_layout)], true);
        let points = make("vs_points", &[Some(&globals_layout), Some(&level_layout)], false);
        let buf = |label, contents: &[u8], usage| {
            let b = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: (contents.len() as u64).max(16).next_multiple_of(16),
                usage: usage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            if !contents.is_empty() {
                queue.write_buffer(&b, 0, contents);
            }
            b
        };
        let rel =
            |p: [f64; 3]| [(p[0] - origin[0]) as f32, (p[1] - origin[1]) as f32, (p[2] - origin[2]) as f32];
        let mut gpu_levels = Vec::with_capacity(levels.len());
        for (blob, spacing, half) in levels {
            match &blob.geometry {
                Geometry::Mesh(m) => {
                    let normals = vertex_normals(&m.positions, &m.triangles);
                    let v: Vec<Vertex> =
                        m.positions.iter().zip(&normals).map(|(p, n)| Vertex { p: rel(*p), n: *n }).collect();
                    let idx: Vec<u32> = m.triangles.iter().flatten().copied().collect();
                    gpu_levels.push(GpuLevel::Mesh {
                        vertices: buf(
                            "instances vertices",
                            bytemuck::cast_slice(&v),
                            wgpu::BufferUsages::VERTEX,
                        ),
                        indices: buf(
                            "instances indices",
                            bytemuck::cast_slice(&idx),
                            wgpu::BufferUsages::INDEX,
                        ),
                        count: idx.len() as u32,
                    });
                }
                Geometry::Points(pc) => {
                    let pts: Vec<Point> = pc
                        .positions
                        .iter()
                        .zip(pc.normals.iter().chain(std::iter::repeat(&[0.0, 0.0, 1.0])))
                        .map(|(p, n)| {
                            let r = rel(*p);
                            Point { p: [r[0], r[1], r[2], 1.0], n: [n[0], n[1], n[2], 0.0] }
                        })
                        .collect();
                    let sb = buf("instances points", bytemuck::cast_slice(&pts), wgpu::BufferUsages::STORAGE);
                    let lv = [*spacing as f32, *half as f32, 0.0, 0.0];
                    let ub = buf("instances level", bytemuck::cast_slice(&lv), wgpu::BufferUsages::UNIFORM);
                    let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some("instances level"),
                        layout: &level_layout,
                        entries: &[
                            wgpu::BindGroupEntry { binding: 0, resource: sb.as_entire_binding() },
                            wgpu::BindGroupEntry { binding: 1, resource: ub.as_entire_binding() },
                        ],
                    });
                    gpu_levels.push(GpuLevel::Points { bind, count: pts.len() as u32 });
                }
            }
        }
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("instances globals"),
            size: std::mem::size_of::<Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let target = |format| {
            device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some("instances target"),
                    size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
                    view_formats: &[],
                })
                .create_view(&wgpu::TextureViewDescriptor::default())
        };
        let color = target(COLOR);
        let depth = target(DEPTH);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(wgpu_err("instances: pipeline creation", e));
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
            globals_layout,
            levels: gpu_levels,
            color,
            depth,
        })
    }

    /// Times `frames` frames (after one warm-up frame) of the instances at `offsets` (world
    /// translations), instance `i` drawn at `levels[i]` (clamped to the model's levels); returns
    /// the per-frame milliseconds and what a frame drew.
    pub fn time_frames(
        &self,
        camera: &Camera,
        far: f64,
        offsets: &[[f64; 3]],
        levels: &[usize],
        frames: u32,
    ) -> Result<(Vec<f64>, FrameCounts), GpuError> {
        let view =
            camera.view().map_err(|e| GpuError::Camera { stage: "instances", message: e.to_string() })?;
        let (near, far) = clip_planes(far);
        let vp = view_proj(&view, self.origin, near, far, f64::from(self.width) / f64::from(self.height));
        let g = Globals {
            view_proj: vp,
            light: [0.4, 0.3, 0.86, 0.0],
            viewport: [self.width as f32, self.height as f32, view.k as f32, 0.0],
        };
        self.queue.write_buffer(&self.globals, 0, bytemuck::bytes_of(&g));
        // Offsets sorted by level: level l draws the instance range ranges[l].
        let nl = self.levels.len();
        let mut order: Vec<usize> = (0..offsets.len()).collect();
        let lv = |i: usize| levels.get(i).copied().unwrap_or(0).min(nl - 1);
        order.sort_by_key(|&i| lv(i));
        let mut counts = FrameCounts { per_level: vec![0; nl], ..FrameCounts::default() };
        let packed: Vec<[f32; 4]> = order
            .iter()
            .map(|&i| {
                counts.per_level[lv(i)] += 1;
                let o = offsets[i];
                [o[0] as f32, o[1] as f32, o[2] as f32, 0.0]
            })
            .collect();
        let obuf = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("instances offsets"),
            size: (std::mem::size_of_val(packed.as_slice()) as u64).max(16),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.queue.write_buffer(&obuf, 0, bytemuck::cast_slice(&packed));
        let bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("instances globals"),
            layout: &self.globals_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: self.globals.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: obuf.as_entire_binding() },
            ],
        });
        let mut start = 0u32;
        let mut ranges = Vec::with_capacity(nl);
        for (l, &c) in counts.per_level.iter().enumerate() {
            ranges.push((l, start..start + c));
            start += c;
            match &self.levels[l] {
                GpuLevel::Mesh { count, .. } => counts.triangles += u64::from(c) * u64::from(*count / 3),
                GpuLevel::Points { count, .. } => counts.points += u64::from(c) * u64::from(*count),
            }
        }
        let mut times = Vec::with_capacity(frames as usize);
        for f in 0..=frames {
            let t0 = Instant::now();
            let mut enc = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("instances") });
            {
                let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("instances"),
                    color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                        view: &self.color,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                            store: wgpu::StoreOp::Store,
                        },
                    })],
                    depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                        view: &self.depth,
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
                pass.set_bind_group(0, &bind, &[]);
                for (l, range) in &ranges {
                    if range.is_empty() {
                        continue;
                    }
                    match &self.levels[*l] {
                        GpuLevel::Mesh { vertices, indices, count } => {
                            pass.set_pipeline(&self.mesh);
                            pass.set_vertex_buffer(0, vertices.slice(..));
                            pass.set_index_buffer(indices.slice(..), wgpu::IndexFormat::Uint32);
                            pass.draw_indexed(0..*count, 0, range.clone());
                        }
                        GpuLevel::Points { bind, count } => {
                            pass.set_pipeline(&self.points);
                            pass.set_bind_group(1, bind, &[]);
                            pass.draw(0..count * 6, range.clone());
                        }
                    }
                }
            }
            self.queue.submit([enc.finish()]);
            self.device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| wgpu_err("instances: waiting for the device", e))?;
            if f > 0 {
                times.push(t0.elapsed().as_secs_f64() * 1e3);
            }
        }
        Ok((times, counts))
    }

    /// Number of levels uploaded.
    #[must_use]
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }
}

/// Area-weighted vertex normals (unit, +Z for isolated vertices).
fn vertex_normals(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    crate::geom::vertex_normal_sums(positions, triangles)
        .into_iter()
        .map(|n| crate::geom::unit_f32(n).unwrap_or([0.0, 0.0, 1.0]))
        .collect()
}

#[cfg(test)]
#[allow(clippy::float_cmp)]
mod tests {
    #[test]
    fn shader_validates_with_naga() {
        let src = super::SHADER;
        let module = naga::front::wgsl::parse_str(src).map_err(|e| e.emit_to_string(src)).unwrap();
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::empty())
            .validate(&module)
            .map_err(|e| e.emit_to_string(src))
            .unwrap();
    }

    #[test]
    fn normals_face_away_from_a_counter_clockwise_triangle() {
        let n = super::vertex_normals(
            &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [5.0, 5.0, 5.0]],
            &[[0, 1, 2]],
        );
        assert_eq!(n[0], [0.0, 0.0, 1.0]);
        assert_eq!(n[3], [0.0, 0.0, 1.0]);
    }
}
