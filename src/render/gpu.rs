//! The wgpu side: device and queue, pipelines, the environment layer texture, frames and readback.

use std::sync::mpsc;

use image::RgbaImage;

use super::RenderError;
use super::environment::{Environment, GroundVertex, Tessellator};
use super::font;
use super::patterns::{PATTERN_SIZE, PatternKind, PatternSet, mip_chain};
use super::sprites::{FrameBatches, VehicleSprite};
use super::view::BirdseyeView;

/// Colour format of every render target and pattern: 8-bit sRGB bytes, no MSAA (deterministic on
/// lavapipe). Deliberately not `Rgba8UnormSrgb`: the shaders work and blend in sRGB space, which
/// saves a conversion per blended pixel (about a third of the frame time on lavapipe).
const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// Uniforms shared by all shaders (see `shaders.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Globals {
    scale: [f32; 2],
    viewport: [f32; 2],
    ppm: f32,
    _pad: [f32; 3],
}

impl Globals {
    fn of(view: &BirdseyeView) -> Globals {
        Globals {
            scale: [
                (2.0 * view.pixels_per_meter / f64::from(view.width)) as f32,
                (2.0 * view.pixels_per_meter_y() / f64::from(view.height)) as f32,
            ],
            viewport: [view.width as f32, view.height as f32],
            ppm: view.pixels_per_meter as f32,
            _pad: [0.0; 3],
        }
    }
}

/// The environment drawn once for one map and view; frames copy it and draw vehicles on top.
#[derive(Debug)]
pub struct EnvironmentLayer {
    view: BirdseyeView,
    texture: wgpu::Texture,
    globals: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

impl EnvironmentLayer {
    /// The view this layer was drawn for (frames on it use the same view).
    pub fn view(&self) -> &BirdseyeView {
        &self.view
    }
}

/// A GPU buffer that grows (to the next power of two) when more data must fit.
#[derive(Debug)]
struct GrowBuffer {
    buffer: Option<wgpu::Buffer>,
    usage: wgpu::BufferUsages,
    label: &'static str,
}

impl GrowBuffer {
    fn new(label: &'static str, usage: wgpu::BufferUsages) -> GrowBuffer {
        GrowBuffer { buffer: None, usage: usage | wgpu::BufferUsages::COPY_DST, label }
    }

    /// Copy `data` in, growing the buffer if needed; `true` when the buffer was replaced.
    fn upload(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, data: &[u8]) -> bool {
        let need = (data.len() as u64).max(1);
        let grow = self.buffer.as_ref().is_none_or(|b| b.size() < need);
        if grow {
            self.buffer = Some(device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(self.label),
                size: need.next_power_of_two().max(256),
                usage: self.usage,
                mapped_at_creation: false,
            }));
        }
        if let (Some(b), false) = (&self.buffer, data.is_empty()) {
            queue.write_buffer(b, 0, data);
        }
        grow
    }

    fn slice(&self, len: u64) -> Option<wgpu::BufferSlice<'_>> {
        if len == 0 { None } else { self.buffer.as_ref().map(|b| b.slice(..len)) }
    }

    fn binding(&self, binding: u32) -> Option<wgpu::BindGroupEntry<'_>> {
        self.buffer.as_ref().map(|b| wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() })
    }
}

/// Frame target and readback buffer for one image size.
#[derive(Debug)]
struct FrameTarget {
    width: u32,
    height: u32,
    texture: wgpu::Texture,
    view: wgpu::TextureView,
    readback: wgpu::Buffer,
}

/// Off-screen bird's-eye renderer: owns the wgpu device and queue, the pipelines and the buffers
/// reused from frame to frame.
#[derive(Debug)]
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: wgpu::AdapterInfo,
    bind_layout: wgpu::BindGroupLayout,
    items_layout: wgpu::BindGroupLayout,
    items: Option<wgpu::BindGroup>,
    ground: wgpu::RenderPipeline,
    sectors: wgpu::RenderPipeline,
    vehicles: wgpu::RenderPipeline,
    labels: wgpu::RenderPipeline,
    sampler: wgpu::Sampler,
    font_view: wgpu::TextureView,
    frame: Option<FrameTarget>,
    batches: FrameBatches,
    route_buf: GrowBuffer,
    sector_buf: GrowBuffer,
    vehicle_buf: GrowBuffer,
    label_buf: GrowBuffer,
}

fn alpha_target() -> [Option<wgpu::ColorTargetState>; 1] {
    [Some(wgpu::ColorTargetState {
        format: FORMAT,
        blend: Some(wgpu::BlendState::ALPHA_BLENDING),
        write_mask: wgpu::ColorWrites::ALL,
    })]
}

/// Turn off Mesa's Vulkan device-selection layer where it has nothing to select by: without
/// `XDG_RUNTIME_DIR` there is no Wayland session, and the layer's attempt to connect to one only
/// prints `error: XDG_RUNTIME_DIR is invalid or not set in the environment.` (libwayland) on
/// stderr, twice per renderer, though nothing failed. Off-screen rendering takes any adapter, so
/// the layer's choice of the display's GPU does not matter here. Its own switch is the
/// `NODEVICE_SELECT=1` environment variable (its manifest's `disable_environment`); a value the
/// user set is kept.
fn quiet_device_select() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        if std::env::var_os("XDG_RUNTIME_DIR").is_none() && std::env::var_os("NODEVICE_SELECT").is_none() {
            // SAFETY: this runs once, before the first Vulkan instance of the process, and every
            // renderer waits here before creating one, so no Vulkan or Mesa code of ours reads the
            // environment meanwhile; Rust's own readers take the standard library's lock.
            unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
        }
    });
}

impl Renderer {
    /// Open any adapter (a software one such as Mesa's lavapipe is fine) and build the pipelines.
    pub fn new() -> Result<Renderer, RenderError> {
        pollster::block_on(Renderer::new_async())
    }

    async fn new_async() -> Result<Renderer, RenderError> {
        quiet_device_select();
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions::default())
            .await
            .map_err(|e| RenderError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        tracing::debug!(adapter = %info.name, backend = ?info.backend, "render adapter");
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("smlworld renderer"),
                required_limits: wgpu::Limits::default().using_resolution(adapter.limits()),
                ..Default::default()
            })
            .await
            .map_err(|e| RenderError::Device(format!("{} ({:?}): {e}", info.name, info.backend)))?;

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("render shaders"),
            source: wgpu::ShaderSource::Wgsl(include_str!("shaders.wgsl").into()),
        });
        let bind_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render globals"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
            ],
        });
        let storage = |binding: u32| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::VERTEX,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let items_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frame items"),
            entries: &[storage(0), storage(1), storage(2)],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("render layout"),
            bind_group_layouts: &[Some(&bind_layout), Some(&items_layout)],
            immediate_size: 0,
        });
        let targets = alpha_target();
        // The ground pipeline also draws the environment layer, where no frame items exist.
        let ground_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("ground layout"),
            bind_group_layouts: &[Some(&bind_layout)],
            immediate_size: 0,
        });
        let pipeline = |label: &str, vs: &str, fs: &str, buffers: &[Option<wgpu::VertexBufferLayout<'_>>]| {
            let layout = if buffers.is_empty() { &layout } else { &ground_layout };
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some(vs),
                    compilation_options: Default::default(),
                    buffers,
                },
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: None,
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets: &targets,
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let ground_attrs = wgpu::vertex_attr_array![0 => Float32x2, 1 => Float32x3, 2 => Float32x4, 3 => Float32x4];
        let ground = pipeline(
            "ground",
            "vs_ground",
            "fs_ground",
            &[Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<GroundVertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &ground_attrs,
            })],
        );
        let sectors = pipeline("sectors", "vs_sector", "fs_sector", &[]);
        let vehicles = pipeline("vehicles", "vs_vehicle", "fs_vehicle", &[]);
        let labels = pipeline("labels", "vs_label", "fs_label", &[]);
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("patterns"),
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        let (fw, fh, fdata) = font::atlas();
        let font_tex = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("font atlas"),
            size: wgpu::Extent3d { width: fw, height: fh, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        queue.write_texture(
            font_tex.as_image_copy(),
            &fdata,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(fw), rows_per_image: None },
            wgpu::Extent3d { width: fw, height: fh, depth_or_array_layers: 1 },
        );
        let font_view = font_tex.create_view(&Default::default());
        let vertex = wgpu::BufferUsages::VERTEX;
        let items = wgpu::BufferUsages::STORAGE;
        Ok(Renderer {
            device,
            queue,
            adapter: info,
            bind_layout,
            items_layout,
            items: None,
            ground,
            sectors,
            vehicles,
            labels,
            sampler,
            font_view,
            frame: None,
            batches: FrameBatches::default(),
            route_buf: GrowBuffer::new("routes", vertex),
            sector_buf: GrowBuffer::new("sectors", items),
            vehicle_buf: GrowBuffer::new("vehicles", items),
            label_buf: GrowBuffer::new("labels", items),
        })
    }

    /// Name and backend of the adapter in use (for logs and benchmark reports).
    pub fn adapter_name(&self) -> String {
        format!("{} ({:?})", self.adapter.name, self.adapter.backend)
    }

    fn pattern_texture(&self, patterns: &PatternSet) -> wgpu::TextureView {
        let mips = mip_chain(&patterns.get(PatternKind::Forest).image).len() as u32;
        let layers = PatternKind::ALL.len() as u32;
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("patterns"),
            size: wgpu::Extent3d { width: PATTERN_SIZE, height: PATTERN_SIZE, depth_or_array_layers: layers },
            mip_level_count: mips,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: FORMAT,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        for kind in PatternKind::ALL {
            for (level, img) in mip_chain(&patterns.get(kind).image).iter().enumerate() {
                self.queue.write_texture(
                    wgpu::TexelCopyTextureInfo {
                        texture: &texture,
                        mip_level: level as u32,
                        origin: wgpu::Origin3d { x: 0, y: 0, z: kind.layer() },
                        aspect: wgpu::TextureAspect::All,
                    },
                    img.as_raw(),
                    wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(4 * img.width()),
                        rows_per_image: None,
                    },
                    wgpu::Extent3d { width: img.width(), height: img.height(), depth_or_array_layers: 1 },
                );
            }
        }
        texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        })
    }

    fn target_texture(&self, label: &str, view: &BirdseyeView, extra: wgpu::TextureUsages) -> wgpu::Texture {
        self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d { width: view.width, height: view.height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC | extra,
            view_formats: &[],
        })
    }

    /// Draw the environment (background, areas, roads, lines) once for `view` into a texture that
    /// every frame then starts from.
    pub fn environment_layer(
        &self,
        env: &Environment,
        view: &BirdseyeView,
        patterns: &PatternSet,
    ) -> Result<EnvironmentLayer, RenderError> {
        let texture = self.target_texture("environment", view, wgpu::TextureUsages::empty());
        let globals = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("globals"),
            size: std::mem::size_of::<Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let pattern_view = self.pattern_texture(patterns);
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("environment"),
            layout: &self.bind_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: globals.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&pattern_view) },
                wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::Sampler(&self.sampler) },
                wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(&self.font_view) },
            ],
        });
        let mut layer = EnvironmentLayer { view: *view, texture, globals, bind_group };
        self.draw_environment(&mut layer, env, view, patterns);
        Ok(layer)
    }

    /// Draw `env` into `layer` again for another view of the same size (a camera that moves);
    /// the layer's textures and buffers are reused. A view of another size gets a new layer.
    pub fn redraw_environment(
        &self,
        layer: &mut EnvironmentLayer,
        env: &Environment,
        view: &BirdseyeView,
        patterns: &PatternSet,
    ) -> Result<(), RenderError> {
        if (layer.view.width, layer.view.height) != (view.width, view.height) {
            *layer = self.environment_layer(env, view, patterns)?;
        } else if layer.view != *view {
            self.draw_environment(layer, env, view, patterns);
        }
        Ok(())
    }

    fn draw_environment(
        &self,
        layer: &mut EnvironmentLayer,
        env: &Environment,
        view: &BirdseyeView,
        patterns: &PatternSet,
    ) {
        let mut vertices = Vec::new();
        Tessellator { view, out: &mut vertices }.environment(env, patterns);
        self.queue.write_buffer(&layer.globals, 0, bytemuck::bytes_of(&Globals::of(view)));
        let mut vbuf = GrowBuffer::new("environment vertices", wgpu::BufferUsages::VERTEX);
        vbuf.upload(&self.device, &self.queue, bytemuck::cast_slice(&vertices));
        let target = layer.texture.create_view(&Default::default());
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("environment"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.ground);
            pass.set_bind_group(0, &layer.bind_group, &[]);
            let bytes = (vertices.len() * std::mem::size_of::<GroundVertex>()) as u64;
            if let Some(slice) = vbuf.slice(bytes) {
                pass.set_vertex_buffer(0, slice);
                pass.draw(0..vertices.len() as u32, 0..1);
            }
        }
        self.queue.submit([encoder.finish()]);
        layer.view = *view;
    }

    /// The environment layer alone, read back.
    pub fn read_environment(&mut self, layer: &EnvironmentLayer) -> Result<RgbaImage, RenderError> {
        self.render_frame(layer, &[])
    }

    /// One frame: the environment layer with `sprites` on top, read back as an image.
    pub fn render_frame(
        &mut self,
        layer: &EnvironmentLayer,
        sprites: &[VehicleSprite],
    ) -> Result<RgbaImage, RenderError> {
        let mut image = RgbaImage::new(layer.view.width, layer.view.height);
        self.render_frame_into(layer, sprites, &mut image)?;
        Ok(image)
    }

    /// Like [`Renderer::render_frame`], writing into `image` (resized if needed), so a sequence of
    /// frames reuses one buffer. Returns the number of sprites skipped for non-finite poses/sizes.
    pub fn render_frame_into(
        &mut self,
        layer: &EnvironmentLayer,
        sprites: &[VehicleSprite],
        image: &mut RgbaImage,
    ) -> Result<usize, RenderError> {
        let view = layer.view;
        let skipped = self.batches.build(&view, sprites);
        if skipped > 0 {
            tracing::warn!(skipped, "vehicles with non-finite pose or non-positive size were not drawn");
        }
        self.ensure_frame(&view);
        let Renderer { device, queue, batches, .. } = self;
        self.route_buf.upload(device, queue, bytemuck::cast_slice(&batches.routes));
        let mut grown = self.sector_buf.upload(device, queue, bytemuck::cast_slice(&batches.sectors));
        grown |= self.vehicle_buf.upload(device, queue, bytemuck::cast_slice(&batches.vehicles));
        grown |= self.label_buf.upload(device, queue, bytemuck::cast_slice(&batches.labels));
        if grown || self.items.is_none() {
            let entries: Vec<wgpu::BindGroupEntry<'_>> =
                [self.sector_buf.binding(0), self.vehicle_buf.binding(1), self.label_buf.binding(2)]
                    .into_iter()
                    .flatten()
                    .collect();
            self.items = Some(self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("frame items"),
                layout: &self.items_layout,
                entries: &entries,
            }));
        }
        let Some(frame) = &self.frame else {
            return Err(RenderError::Readback("frame target missing".into()));
        };
        let mut encoder = self.device.create_command_encoder(&Default::default());
        let extent = wgpu::Extent3d { width: view.width, height: view.height, depth_or_array_layers: 1 };
        encoder.copy_texture_to_texture(layer.texture.as_image_copy(), frame.texture.as_image_copy(), extent);
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("frame"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &frame.view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: wgpu::LoadOp::Load, store: wgpu::StoreOp::Store },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_bind_group(0, &layer.bind_group, &[]);
            let b = &self.batches;
            let size = |n: usize, s: usize| (n * s) as u64;
            if let Some(s) = self.route_buf.slice(size(b.routes.len(), std::mem::size_of::<GroundVertex>())) {
                pass.set_pipeline(&self.ground);
                pass.set_vertex_buffer(0, s);
                pass.draw(0..b.routes.len() as u32, 0..1);
            }
            if let Some(items) = &self.items {
                pass.set_bind_group(1, items, &[]);
                let counts = [
                    (&self.sectors, b.sectors.len()),
                    (&self.vehicles, b.vehicles.len()),
                    (&self.labels, b.labels.len()),
                ];
                for (pipeline, n) in counts {
                    if n > 0 {
                        pass.set_pipeline(pipeline);
                        pass.draw(0..6 * n as u32, 0..1);
                    }
                }
            }
        }
        read_back(&self.device, &self.queue, encoder, frame, image)?;
        Ok(skipped)
    }

    fn ensure_frame(&mut self, view: &BirdseyeView) {
        if self.frame.as_ref().is_some_and(|f| f.width == view.width && f.height == view.height) {
            return;
        }
        let texture = self.target_texture("frame", view, wgpu::TextureUsages::COPY_DST);
        let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded_row(view.width)) * u64::from(view.height),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let tview = texture.create_view(&Default::default());
        self.frame = Some(FrameTarget { width: view.width, height: view.height, texture, view: tview, readback });
    }
}

/// Bytes per row on the copy: 4 bytes per pixel, padded to wgpu's 256-byte alignment.
fn padded_row(width: u32) -> u32 {
    (4 * width).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT
}

fn read_back(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    mut encoder: wgpu::CommandEncoder,
    frame: &FrameTarget,
    image: &mut RgbaImage,
) -> Result<(), RenderError> {
    let row = padded_row(frame.width);
    encoder.copy_texture_to_buffer(
        frame.texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &frame.readback,
            layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(row), rows_per_image: None },
        },
        wgpu::Extent3d { width: frame.width, height: frame.height, depth_or_array_layers: 1 },
    );
    queue.submit([encoder.finish()]);
    let (tx, rx) = mpsc::channel();
    frame.readback.map_async(wgpu::MapMode::Read, .., move |r| {
        // The receiver waits right below; a failed send only means it has gone away.
        let _ = tx.send(r);
    });
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| RenderError::Readback(e.to_string()))?;
    rx.recv().map_err(|e| RenderError::Readback(e.to_string()))?.map_err(|e| RenderError::Readback(e.to_string()))?;
    if image.width() != frame.width || image.height() != frame.height {
        *image = RgbaImage::new(frame.width, frame.height);
    }
    {
        let mapped = frame.readback.get_mapped_range(..).map_err(|e| RenderError::Readback(e.to_string()))?;
        let tight = 4 * frame.width as usize;
        let out: &mut [u8] = image;
        for (dst, src) in out.chunks_exact_mut(tight).zip(mapped.chunks_exact(row as usize)) {
            dst.copy_from_slice(&src[..tight]);
        }
    }
    frame.readback.unmap();
    Ok(())
}
