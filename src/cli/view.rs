//! `smlworld view`: live bird's-eye viewer of the UDP visualisation stream.
//!
//! Frames come from [`VizReceiver`] (newest complete frame wins), are drawn by the off-screen
//! renderer over the map's environment layer, and are shown in an X11 window (winit) by copying
//! the image into it with softbuffer, which needs no Vulkan surface (so it works under Xvfb and
//! with software rendering). The window is redrawn whenever a newer frame has arrived, checked
//! every [`POLL`]. Without a display (no `DISPLAY`, or the window cannot open) it says so and,
//! with `--frames DIR`, writes every new frame as a PNG instead.

use std::net::SocketAddr;
use std::num::NonZeroU32;
use std::path::PathBuf;
use std::rc::Rc;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use glam::DVec2;
use image::RgbaImage;
use smlworld::io::viz::{DEFAULT_VIZ_ADDR, VizFrame, VizReceiver, viewer_body};
use smlworld::map::LaneletMap;
use smlworld::render::{
    BirdseyeView, Environment, EnvironmentLayer, PatternSet, Renderer, VehicleSprite, frame_path, write_image,
};
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::window::{Window, WindowId};

/// How often the viewer checks for a newer frame.
const POLL: Duration = Duration::from_millis(10);

/// Arguments of `smlworld view`.
#[derive(Debug, clap::Args)]
pub struct ViewArgs {
    /// UDP address to receive the stream on.
    #[arg(long, default_value_t = DEFAULT_VIZ_ADDR)]
    pub listen: SocketAddr,
    /// Format of the stream: `smlworld` (ours; x, y the body centre) or `2015` (a 2015 sender's:
    /// x, y the rear-axle point, drawn where the 2015 viewer draws it).
    #[arg(long, value_name = "FORMAT", default_value = "smlworld", value_parser = super::run::parse_stream_format)]
    pub stream_format: smlworld::io::viz::StreamFormat,
    /// Lanelet map drawn as the background (the view then fits the map).
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Window (or frame) width [px].
    #[arg(long, default_value_t = 1280, value_parser = super::range::pixels())]
    pub width: u32,
    /// Window (or frame) height [px].
    #[arg(long, default_value_t = 720, value_parser = super::range::pixels())]
    pub height: u32,
    /// Scale [px/m] (default: fit the map, else 4).
    #[arg(long, value_parser = super::range::positive)]
    pub pixels_per_meter: Option<f64>,
    /// View centre `X,Y` [m] (default: the map's centre, else the origin).
    #[arg(long, value_parser = super::range::point, allow_hyphen_values = true)]
    pub center: Option<DVec2>,
    /// Write every new frame as DIR/frame_NNNNNN.png (and, without a display, only that).
    #[arg(long, value_name = "DIR")]
    pub frames: Option<PathBuf>,
    /// Stop after this many seconds (default: run until closed or stopped with Ctrl-C).
    #[arg(long, value_parser = super::range::positive)]
    pub duration: Option<f64>,
    /// Most frames per wall-clock second written to --frames [Hz]; newer frames in between are
    /// shown but not written (the stream runs at 50 Hz: 1.7 GB of PNGs in 25 s unthrottled).
    #[arg(long, default_value_t = 10.0, value_parser = super::range::positive)]
    pub frame_rate: f64,
}

/// The receiving and drawing half of the viewer (no window).
struct Scene {
    receiver: VizReceiver,
    renderer: Renderer,
    env: Environment,
    patterns: PatternSet,
    map: Option<LaneletMap>,
    args: ViewArgs,
    layer: EnvironmentLayer,
    image: RgbaImage,
    sprites: Vec<VehicleSprite>,
    drawn: Option<u64>,
    written: u64,
    /// When the next frame may be written to --frames (wall clock).
    next_write: Instant,
}

impl Scene {
    fn new(args: ViewArgs) -> anyhow::Result<Scene> {
        anyhow::ensure!(args.width > 0 && args.height > 0, "--width and --height must be at least 1 px");
        if let Some(p) = args.pixels_per_meter {
            anyhow::ensure!(p.is_finite() && p > 0.0, "--pixels-per-meter must be positive, got {p}");
        }
        if let Some(d) = args.duration {
            anyhow::ensure!(d.is_finite() && d > 0.0, "--duration must be a positive number of seconds, got {d}");
        }
        smlworld::render::check_frame_rate(args.frame_rate).map_err(anyhow::Error::msg)?;
        let map = match &args.map {
            Some(path) => {
                Some(LaneletMap::load(path).with_context(|| format!("cannot load the map {}", path.display()))?)
            }
            None => None,
        };
        let env = match &map {
            Some(m) => Environment::from_map(m),
            None => Environment {
                background: smlworld::render::PatternKind::Forest,
                areas: Vec::new(),
                roads: Vec::new(),
                lines: Vec::new(),
            },
        };
        if let Some(dir) = &args.frames {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create the frame folder {}", dir.display()))?;
        }
        let receiver =
            VizReceiver::bind(args.listen).with_context(|| format!("cannot listen on udp://{}", args.listen))?;
        let renderer = Renderer::new()?;
        let patterns = PatternSet::builtin();
        let view = view_for(&args, map.as_ref(), args.width, args.height)?;
        let layer = renderer.environment_layer(&env, &view, &patterns)?;
        tracing::info!("listening for the visualisation stream on udp://{}", receiver.local_addr());
        Ok(Scene {
            receiver,
            renderer,
            env,
            patterns,
            map,
            args,
            layer,
            image: RgbaImage::new(1, 1),
            sprites: Vec::new(),
            drawn: None,
            written: 0,
            next_write: Instant::now(),
        })
    }

    /// Redraw the environment layer for a new size [px].
    fn resize(&mut self, width: u32, height: u32) -> anyhow::Result<()> {
        let view = view_for(&self.args, self.map.as_ref(), width, height)?;
        self.layer = self.renderer.environment_layer(&self.env, &view, &self.patterns)?;
        self.drawn = None;
        Ok(())
    }

    /// The newest frame if it is newer than the one drawn last.
    fn newer(&self) -> Option<VizFrame> {
        self.receiver.latest().filter(|f| self.drawn.is_none_or(|d| f.counter > d))
    }

    /// Render `frame` (or no vehicles) into `self.image`, and write it to `--frames` if asked.
    fn draw(&mut self, frame: Option<&VizFrame>) -> anyhow::Result<()> {
        self.sprites.clear();
        if let Some(f) = frame {
            let format = self.args.stream_format;
            self.sprites.extend(f.vehicles.iter().map(|v| {
                let (centre, yaw, length, width) = viewer_body(format, v);
                VehicleSprite::new(v.id, centre, yaw, length, width, &v.class_name)
            }));
            self.drawn = Some(f.counter);
        }
        self.renderer.render_frame_into(&self.layer, &self.sprites, &mut self.image)?;
        if let (Some(dir), Some(_)) = (&self.args.frames, frame) {
            let now = Instant::now();
            if now >= self.next_write {
                write_image(&frame_path(dir, self.written), &self.image)?;
                self.written += 1;
                self.next_write = now + Duration::from_secs_f64(1.0 / self.args.frame_rate);
            }
        }
        Ok(())
    }
}

fn view_for(args: &ViewArgs, map: Option<&LaneletMap>, width: u32, height: u32) -> anyhow::Result<BirdseyeView> {
    let fitted = match map {
        Some(m) => BirdseyeView::fit_map(width, height, m)?,
        None => BirdseyeView::centered_on_origin(width, height, 4.0)?,
    };
    Ok(BirdseyeView::new(
        width,
        height,
        args.pixels_per_meter.unwrap_or(fitted.pixels_per_meter),
        args.center.unwrap_or(fitted.center),
    )?)
}

/// Run the subcommand.
pub fn main(args: ViewArgs) -> anyhow::Result<()> {
    let deadline = args.duration.map(|d| Instant::now() + Duration::from_secs_f64(d));
    let has_frames = args.frames.is_some();
    let mut scene = Scene::new(args)?;
    let why = if std::env::var_os("DISPLAY").is_none() {
        "no display: DISPLAY is not set (the viewer opens an X11 window; XWayland and Xvfb work)".to_string()
    } else {
        match run_window(&mut scene, deadline)? {
            Ok(()) => return Ok(()),
            Err(e) => format!("no display: the window could not open ({e:#})"),
        }
    };
    if !has_frames {
        anyhow::bail!("{why}; give --frames DIR to write PNG frames instead");
    }
    eprintln!(
        "{why}; writing frames to {} instead",
        scene.args.frames.as_deref().unwrap_or(std::path::Path::new("")).display()
    );
    run_frames(&mut scene, deadline)
}

/// Headless: write every new frame until the deadline (or forever).
fn run_frames(scene: &mut Scene, deadline: Option<Instant>) -> anyhow::Result<()> {
    while deadline.is_none_or(|d| Instant::now() < d) {
        let after = scene.drawn;
        if let Some(f) = scene.receiver.wait_newer(after, Duration::from_millis(100)) {
            scene.draw(Some(&f))?;
        }
    }
    Ok(())
}

/// The window half of the viewer (winit application).
struct WindowApp<'a> {
    scene: &'a mut Scene,
    deadline: Option<Instant>,
    window: Option<Rc<Window>>,
    surface: Option<softbuffer::Surface<Rc<Window>, Rc<Window>>>,
    opened: bool,
    error: Option<anyhow::Error>,
}

/// Show frames in a window until it is closed or the deadline passes. `Ok(Err(why))`: no
/// window could be opened (no display); `Err`: a failure after the window was open.
fn run_window(scene: &mut Scene, deadline: Option<Instant>) -> anyhow::Result<Result<(), anyhow::Error>> {
    let event_loop = match EventLoop::new() {
        Ok(l) => l,
        Err(e) => return Ok(Err(anyhow::anyhow!("cannot connect to the display: {e}"))),
    };
    let mut app = WindowApp { scene, deadline, window: None, surface: None, opened: false, error: None };
    let run = event_loop.run_app(&mut app);
    match (app.error, app.opened) {
        (Some(e), false) => Ok(Err(e)),
        (Some(e), true) => Err(e),
        (None, _) => run.context("window event loop").map(Ok),
    }
}

impl WindowApp<'_> {
    fn open(&mut self, event_loop: &ActiveEventLoop) -> anyhow::Result<()> {
        let attrs = Window::default_attributes()
            .with_title("SML World")
            .with_inner_size(PhysicalSize::new(self.scene.args.width, self.scene.args.height))
            .with_position(PhysicalPosition::new(0, 0));
        let window = Rc::new(event_loop.create_window(attrs).context("cannot create a window")?);
        let context =
            softbuffer::Context::new(window.clone()).map_err(|e| anyhow::anyhow!("softbuffer context: {e}"))?;
        let surface = softbuffer::Surface::new(&context, window.clone())
            .map_err(|e| anyhow::anyhow!("softbuffer surface: {e}"))?;
        self.window = Some(window);
        self.surface = Some(surface);
        self.opened = true;
        tracing::info!("viewer window open");
        Ok(())
    }

    fn redraw(&mut self) -> anyhow::Result<()> {
        let (Some(window), Some(surface)) = (&self.window, &mut self.surface) else { return Ok(()) };
        let size = window.inner_size();
        let (Some(w), Some(h)) = (NonZeroU32::new(size.width), NonZeroU32::new(size.height)) else { return Ok(()) };
        let view = self.scene.layer.view();
        if (view.width, view.height) != (size.width, size.height) {
            self.scene.resize(size.width, size.height)?;
        }
        let frame = self.scene.newer();
        if frame.is_some() || self.scene.drawn.is_none() {
            self.scene.draw(frame.as_ref())?;
        }
        surface.resize(w, h).map_err(|e| anyhow::anyhow!("resize the window buffer: {e}"))?;
        let mut buffer = surface.buffer_mut().map_err(|e| anyhow::anyhow!("window buffer: {e}"))?;
        let image = &self.scene.image;
        for (dst, px) in buffer.iter_mut().zip(image.pixels()) {
            let [r, g, b, _] = px.0;
            *dst = (u32::from(r) << 16) | (u32::from(g) << 8) | u32::from(b);
        }
        buffer.present().map_err(|e| anyhow::anyhow!("present the window buffer: {e}"))?;
        Ok(())
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, e: anyhow::Error) {
        self.error = Some(e);
        event_loop.exit();
    }
}

impl ApplicationHandler for WindowApp<'_> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_none()
            && let Err(e) = self.open(event_loop)
        {
            self.fail(event_loop, e);
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(_) => {
                if let Some(w) = &self.window {
                    w.request_redraw();
                }
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        if self.deadline.is_some_and(|d| Instant::now() >= d) {
            event_loop.exit();
            return;
        }
        if let Some(w) = &self.window
            && self.scene.newer().is_some()
        {
            w.request_redraw();
        }
        event_loop.set_control_flow(ControlFlow::WaitUntil(Instant::now() + POLL));
    }
}
