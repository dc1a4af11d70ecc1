//! The GPU device layer: opening an adapter and device, the error type, a render pipeline
//! helper and WGSL shader modules. It sits below its users (the point-level bake in
//! `lod::gpu`, the client's renderer and the evaluation) and imports none of them: they
//! import it.

/// A GPU stage failure.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "gpu: no adapter found (no Vulkan, Metal or DX12 device, not even a software one such as Mesa lavapipe)"
    )]
    NoAdapter,
    #[error("gpu: cannot open a device on adapter {adapter}: {message}")]
    Device { adapter: String, message: String },
    /// wgpu refused or lost work (validation, out of memory, device lost, mapping): what was
    /// being done, and wgpu's own message.
    #[error("gpu: {during}: {message}")]
    Wgpu { during: String, message: String },
    #[error("gpu: adapter {adapter} allows {got} storage buffers per shader stage, the bake needs {needed}")]
    StorageBindings { adapter: String, got: u32, needed: u32 },
    #[error("gpu: {stage}: viewport {width}×{height} (1 to {max} per side)")]
    Viewport { stage: &'static str, width: u32, height: u32, max: u32 },
    #[error("gpu: render: clip planes {near}..{far} (need 0 < near < far)")]
    ClipPlanes { near: f64, far: f64 },
    /// The camera has no view (not finite, or eye = target).
    #[error("gpu: {stage}: {message}")]
    Camera { stage: &'static str, message: String },
    #[error("gpu: instances: level 0 of the model is not a mesh")]
    NotAMesh,
    /// An invariant of our own GPU code did not hold (a bug, not an input problem).
    #[error("gpu: {0}")]
    Internal(&'static str),
}

/// A device and queue with the name of their adapter.
pub struct GpuContext {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub adapter: String,
    /// The adapter runs on the CPU (Mesa lavapipe, WARP, SwiftShader): fine for rendering,
    /// several times slower than the CPU reference for baking.
    pub software: bool,
}

/// Opens the first adapter wgpu offers (hardware preferred, any software one such as Mesa's
/// lavapipe accepted) with its full limits.
pub fn open() -> Result<GpuContext, GpuError> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        ..Default::default()
    }))
    .or_else(|_| {
        pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            force_fallback_adapter: true,
            ..Default::default()
        }))
    })
    .map_err(|_| GpuError::NoAdapter)?;
    let info = adapter.get_info();
    let name = describe(&info);
    let software = info.device_type == wgpu::DeviceType::Cpu;
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("terrastream"),
        required_limits: adapter.limits(),
        ..Default::default()
    }))
    .map_err(|e| GpuError::Device { adapter: name.clone(), message: e.to_string() })?;
    Ok(GpuContext { device, queue, adapter: name, software })
}

/// "name (backend, device type)", e.g. "llvmpipe (LLVM 19.1.7, 256 bits) (Vulkan, Cpu)".
#[must_use]
pub fn describe(info: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type)
}

/// A render pipeline that draws opaque triangle lists of `module` (vertex entry `vs_entry`,
/// fragment entry `fs_main`) into one `color` target with a depth test (`Less`, depth
/// written) on `depth`, no culling, no blending, no multisampling: how the client's renderer and
/// the instance experiment draw.
#[must_use]
pub fn opaque_pipeline(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
    vs_entry: &str,
    buffers: &[Option<wgpu::VertexBufferLayout<'_>>],
    (color, depth): (wgpu::TextureFormat, wgpu::TextureFormat),
) -> wgpu::RenderPipeline {
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(label),
        layout: Some(layout),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some(vs_entry),
            compilation_options: wgpu::PipelineCompilationOptions::default(),
            buffers,
        },
        primitive: wgpu::PrimitiveState::default(),
        depth_stencil: Some(wgpu::DepthStencilState {
            format: depth,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: wgpu::StencilState::default(),
            bias: wgpu::DepthBiasState::default(),
        }),
        multisample: wgpu::MultisampleState::default(),
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some("fs_main"),
            compilation_options: wgpu::PipelineCompilationOptions::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format: color,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// A WGSL shader module (the WGSL sources live in `shaders/bake/` and `shaders/render/`).
#[must_use]
pub fn shader_module(device: &wgpu::Device, label: &str, source: &str) -> wgpu::ShaderModule {
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    })
}
