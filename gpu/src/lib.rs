//! # terrabake-gpu
//!
//! The reference WGSL shader (`src/cone_step.wgsl`): cone stepping through
//! the cone texture terrabake exports (`export --layer cone_slope -o
//! cones.ktx2`) and shading each hit with the exported horizon array
//! (`export --layer horizon -o horizons.ktx2`), one ray per invocation, in
//! f32, run through wgpu on
//! whatever adapter the machine has (Mesa's lavapipe, software Vulkan, where
//! there is no GPU). Its hits are compared with the CPU parametric tracer
//! (tests/shader.rs). It depends on the format crate alone, as a renderer
//! would.
//!
//! This is a reference for renderers to read and port, not a renderer: it
//! traces a batch of rays and reads the hits back.

use bytemuck::{Pod, Zeroable};
use terrabake_format::trace::{grid_ray, Ray};
use wgpu::util::DeviceExt;

/// The shader's source.
pub const SHADER: &str = include_str!("cone_step.wgsl");

/// Heights the shader takes for nodata (it reads no NaN: WGSL does not
/// promise to keep them).
pub const NODATA: f32 = -3.0e38;

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Params {
    cells: [u32; 2],
    posts_x: u32,
    rays: u32,
    dx: f32,
    dy: f32,
    max_steps: u32,
    bands: u32,
    sun: [f32; 3],
    horizon_decode: [f32; 2],
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct GpuRay {
    origin: [f32; 4],
    dir: [f32; 4],
}

/// One ray's result from the shader.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct GpuHit {
    pub t: f32,
    /// `c + r * cells_x`, or `u32::MAX` for a miss.
    pub cell: u32,
    pub cells_tested: u32,
    pub leaps: u32,
    /// The lit share of the sun's disc at the hit's nearest post, or -1
    /// (a miss, nodata, or no horizons).
    pub lit: f32,
}

impl GpuHit {
    /// The cell hit, `(c, r)`.
    pub fn cell(&self, cells_x: u32) -> Option<(u32, u32)> {
        (self.cell != u32::MAX).then(|| (self.cell % cells_x, self.cell / cells_x))
    }
}

/// The terrain as the shader reads it.
#[derive(Debug)]
pub struct Scene<'a> {
    /// Posts, row by row from the north; NaN for nodata.
    pub heights: &'a [f32],
    pub posts: (u32, u32),
    /// Metres between posts.
    pub spacing: (f64, f64),
    /// The exported cone texture: (apex, slope) per cell.
    pub cones: &'a [[f32; 2]],
    /// The exported horizon array and the sun to shade with, if any.
    pub shading: Option<Shading<'a>>,
}

/// What the shader shades hits with: the exported 16-bit horizon array
/// (`export --layer horizon -o X.ktx2`), its decoding, and the sun.
#[derive(Debug)]
pub struct Shading<'a> {
    /// Codes, band after band, one per post; 0 is nodata.
    pub codes: &'a [u16],
    /// Degrees = `offset + scale * code`.
    pub decode: (f64, f64),
    /// The bands' compass azimuths, degrees, ascending.
    pub azimuths: &'a [f64],
    /// Compass azimuth, elevation and angular radius of the sun, degrees.
    pub sun: [f64; 3],
}

/// A device and the compiled shader.
#[derive(Debug)]
pub struct Gpu {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::ComputePipeline,
    /// What the adapter says it is (name, backend, device type).
    pub adapter: String,
}

impl Gpu {
    /// The first adapter wgpu finds (a software one included), or why none.
    pub fn new() -> Result<Self, String> {
        pollster::block_on(async {
            let instance = wgpu::Instance::new(&wgpu::InstanceDescriptor {
                backends: wgpu::Backends::VULKAN,
                ..Default::default()
            });
            let adapter = instance
                .request_adapter(&wgpu::RequestAdapterOptions::default())
                .await
                .map_err(|e| format!("no Vulkan adapter: {e} (install Mesa's lavapipe: apt-get install mesa-vulkan-drivers)"))?;
            let info = adapter.get_info();
            let (device, queue) = adapter
                .request_device(&wgpu::DeviceDescriptor {
                    label: Some("terrabake-gpu"),
                    // WebGPU's default of 8 storage buffers (downlevel has 4).
                    required_limits: wgpu::Limits {
                        max_storage_buffers_per_shader_stage: 8,
                        ..wgpu::Limits::downlevel_defaults().using_resolution(adapter.limits())
                    },
                    ..Default::default()
                })
                .await
                .map_err(|e| format!("{}: cannot open the device: {e}", info.name))?;
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("cone_step.wgsl"),
                source: wgpu::ShaderSource::Wgsl(SHADER.into()),
            });
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("cone_step"),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            });
            Ok(Self {
                device,
                queue,
                pipeline,
                adapter: format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type),
            })
        })
    }

    /// Traces `rays` (local metres, as the CPU tracer takes them) through
    /// `scene` and reads the hits back; `t` is the rays' own parameter.
    pub fn trace(&self, scene: &Scene, rays: &[Ray]) -> Vec<GpuHit> {
        let (pw, ph) = scene.posts;
        let (dx, dy) = scene.spacing;
        let gpu_rays: Vec<GpuRay> = rays
            .iter()
            .map(|r| {
                let g = grid_ray(r, scene.spacing, ph);
                let [o, d] = [g.origin, g.dir].map(|v| v.map(|x| x as f32));
                GpuRay {
                    origin: [o[0], o[1], o[2], r.t_max.min(f64::from(f32::MAX)) as f32],
                    dir: [d[0], d[1], d[2], 0.0],
                }
            })
            .collect();
        let heights: Vec<f32> = scene
            .heights
            .iter()
            .map(|&z| if z.is_nan() { NODATA } else { z })
            .collect();
        let shading = scene.shading.as_ref();
        let params = Params {
            cells: [pw - 1, ph - 1],
            posts_x: pw,
            rays: rays.len() as u32,
            dx: dx as f32,
            dy: dy as f32,
            max_steps: 4 * (pw + ph) + 64,
            bands: shading.map_or(0, |s| s.azimuths.len() as u32),
            sun: shading.map_or([0.0; 3], |s| s.sun.map(|v| v as f32)),
            horizon_decode: shading.map_or([0.0; 2], |s| [s.decode.0 as f32, s.decode.1 as f32]),
            _pad: [0; 3],
        };
        // Storage buffers may not be empty: one dummy element without shading.
        let codes: Vec<u32> =
            shading.map_or(vec![0], |s| s.codes.iter().map(|&c| u32::from(c)).collect());
        let azimuths: Vec<f32> = shading.map_or(vec![0.0], |s| {
            s.azimuths.iter().map(|&a| a as f32).collect()
        });
        let d = &self.device;
        let buffer = |label, bytes: &[u8], usage| {
            d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage,
            })
        };
        let storage = wgpu::BufferUsages::STORAGE;
        let params_buf = buffer(
            "params",
            bytemuck::bytes_of(&params),
            wgpu::BufferUsages::UNIFORM,
        );
        let heights_buf = buffer("heights", bytemuck::cast_slice(&heights), storage);
        let cones_buf = buffer("cones", bytemuck::cast_slice(scene.cones), storage);
        let rays_buf = buffer("rays", bytemuck::cast_slice(&gpu_rays), storage);
        let codes_buf = buffer("horizon", bytemuck::cast_slice(&codes), storage);
        let azimuths_buf = buffer("azimuths", bytemuck::cast_slice(&azimuths), storage);
        let size = (rays.len().max(1) * std::mem::size_of::<GpuHit>()) as u64;
        let hits_buf = d.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hits"),
            size,
            usage: storage | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let read_buf = d.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read back"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &[
                (0, &params_buf),
                (1, &heights_buf),
                (2, &cones_buf),
                (3, &rays_buf),
                (4, &hits_buf),
                (5, &codes_buf),
                (6, &azimuths_buf),
            ]
            .map(|(binding, b)| wgpu::BindGroupEntry {
                binding,
                resource: b.as_entire_binding(),
            }),
        });
        let mut encoder = d.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &bind, &[]);
            pass.dispatch_workgroups((rays.len() as u32).div_ceil(64), 1, 1);
        }
        encoder.copy_buffer_to_buffer(&hits_buf, 0, &read_buf, 0, size);
        self.queue.submit([encoder.finish()]);
        let slice = read_buf.slice(..);
        slice.map_async(wgpu::MapMode::Read, |r| r.expect("map the hits"));
        d.poll(wgpu::PollType::wait_indefinitely())
            .expect("the device finishes");
        let hits = bytemuck::cast_slice::<u8, GpuHit>(&slice.get_mapped_range()).to_vec();
        hits[..rays.len()].to_vec()
    }
}
