//! `smlworld view`: live bird's-eye viewer of the UDP visualisation stream.
//!
//! Frames come from [`VizReceiver`] (newest complete frame wins), are drawn by the off-screen
//! renderer over the map's environment layer, and are shown in an X11 window (winit) by copying
//! the image into it with softbuffer, which needs no Vulkan surface (so it works under Xvfb and
//! with software rendering). The window is redrawn whenever a newer frame has arrived, checked
//! every [`POLL`]. With `--map`, the stop lines of signalised junctions are drawn in the colours
//! of the stream's light states (our format's lights extension). Without a display (no
//! `DISPLAY`, or the window cannot open) it says so and, with `--frames DIR`, writes every new
//! frame as a PNG instead.

use std::collections::BTreeSet;
use std::net::SocketAddr;
use std::num::NonZeroU32;
use std::path::PathBuf;
use std::rc::Rc;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use image::RgbaImage;
use smlworld::app::results::lights::SignalLines;
use smlworld::io::viz::{DEFAULT_VIZ_ADDR, VizFrame, VizReceiver, viewer_body};
use smlworld::map::LaneletMap;
use smlworld::render::{Environment, FrameOutput, FrameRecorder, Overlay, VehicleSprite};
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
    /// Window size, view (--follow, --pixels-per-meter, --center), overlay, and frames written
    /// to --frames/--gif (at most --frame-rate per wall-clock second: the stream runs at 50 Hz,
    /// 1.7 GB of PNGs in 25 s unthrottled). Without a map the view is centred on the origin at
    /// 4 px/m unless --pixels-per-meter says otherwise.
    #[command(flatten)]
    pub frame_output: FrameOutput,
    /// Stop after this many seconds (default: run until closed or stopped with Ctrl-C).
    #[arg(long, value_parser = super::range::positive)]
    pub duration: Option<f64>,
}

/// The receiving and drawing half of the viewer (no window).
struct Scene {
    receiver: VizReceiver,
    recorder: FrameRecorder,
    args: ViewArgs,
    sprites: Vec<VehicleSprite>,
    /// The map's stop lines, drawn in the colours the stream's light states give (none without
    /// a map).
    signals: Option<SignalLines>,
    /// Pairs of vehicles whose footprints overlapped in the last frame (a new pair is a
    /// collision: a red ring for 2 s).
    touching: BTreeSet<(i32, i32)>,
    drawn: Option<u64>,
    /// Time of the first frame received (frame times count from it).
    start: Option<Instant>,
    /// When the next frame may be written to --frames/--gif (wall clock).
    next_write: Instant,
}

impl Scene {
    fn new(args: ViewArgs) -> anyhow::Result<Scene> {
        if let Some(d) = args.duration {
            anyhow::ensure!(d.is_finite() && d > 0.0, "--duration must be a positive number of seconds, got {d}");
        }
        args.frame_output.check().map_err(anyhow::Error::msg)?;
        let map = match &args.map {
            Some(path) => {
                Some(LaneletMap::load(path).with_context(|| format!("cannot load the map {}", path.display()))?)
            }
            None => None,
        };
        let (env, map_box) = match &map {
            Some(m) if !m.nodes.is_empty() => (Environment::from_map(m), Some(m.bounding_box())),
            Some(m) => (Environment::from_map(m), None),
            None => (
                Environment {
                    background: smlworld::render::PatternKind::Forest,
                    areas: Vec::new(),
                    roads: Vec::new(),
                    fills: Vec::new(),
                    lines: Vec::new(),
                },
                None,
            ),
        };
        let signals = map.as_ref().map(SignalLines::of_map);
        let receiver =
            VizReceiver::bind(args.listen).with_context(|| format!("cannot listen on udp://{}", args.listen))?;
        let recorder = FrameRecorder::with_environment(env, map_box, &args.frame_output)?;
        tracing::info!("listening for the visualisation stream on udp://{}", receiver.local_addr());
        Ok(Scene {
            receiver,
            recorder,
            args,
            sprites: Vec::new(),
            signals,
            touching: BTreeSet::new(),
            drawn: None,
            start: None,
            next_write: Instant::now(),
        })
    }

    /// Draw later frames at a new size [px] (a resized window).
    fn resize(&mut self, width: u32, height: u32) -> anyhow::Result<()> {
        self.recorder.resize(width, height)?;
        self.drawn = None;
        Ok(())
    }

    /// The newest frame if it is newer than the one drawn last.
    fn newer(&self) -> Option<VizFrame> {
        self.receiver.latest().filter(|f| self.drawn.is_none_or(|d| f.counter > d))
    }

    /// Render `frame` (or the last vehicles) and write it to --frames/--gif if one is due;
    /// returns the image.
    fn draw(&mut self, frame: Option<&VizFrame>) -> anyhow::Result<&RgbaImage> {
        let now = Instant::now();
        let t = self.start.map_or(0.0, |s| now.duration_since(s).as_secs_f64());
        if let Some(f) = frame {
            self.start.get_or_insert(now);
            let format = self.args.stream_format;
            self.sprites.clear();
            self.sprites.extend(f.vehicles.iter().map(|v| {
                let (centre, yaw, length, width) = viewer_body(format, v);
                let mut sprite = VehicleSprite::new(v.id, centre, yaw, length, width, &v.class_name);
                // The stream says nothing of where a state comes from: the lab's convention
                // (its bridges drive ids >= 0) is all the viewer has.
                sprite.real = v.id >= 0;
                // A lane change in progress (our stream format sends it).
                sprite.overlays.indicator = v.indicator;
                sprite
            }));
            self.sprites.sort_by_key(|s| s.id);
            // The stream carries no collisions: footprints that start to overlap are one.
            let touching = smlworld::render::overlapping_pairs(&self.sprites);
            for (a, b, place) in &touching {
                if !self.touching.contains(&(*a, *b)) {
                    self.recorder.add_collision(*place, t);
                }
            }
            self.touching = touching.into_iter().map(|(a, b, _)| (a, b)).collect();
            self.drawn = Some(f.counter);
            if let Some(signals) = self.signals.as_mut() {
                self.recorder.set_signals(signals.from_states(f.lights.iter().map(|l| (l.junction, l.state.as_str()))));
            }
        }
        self.recorder.draw(&self.sprites, t)?;
        if frame.is_some() && self.args.frame_output.any() && now >= self.next_write {
            self.recorder.write_drawn(&self.sprites, t)?;
            self.next_write = now + Duration::from_secs_f64(1.0 / self.args.frame_output.frame_rate);
        }
        if self.args.frame_output.overlay == Overlay::All {
            self.recorder.overlay_drawn(&self.sprites, t);
        }
        Ok(self.recorder.drawn())
    }
}

/// Run the subcommand.
pub fn main(args: ViewArgs) -> anyhow::Result<()> {
    let deadline = args.duration.map(|d| Instant::now() + Duration::from_secs_f64(d));
    let has_frames = args.frame_output.any();
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
        anyhow::bail!("{why}; give --frames DIR (or --gif FILE.gif) to write frames instead");
    }
    eprintln!(
        "{why}; writing frames to {} instead",
        scene
            .args
            .frame_output
            .frames
            .iter()
            .chain(&scene.args.frame_output.gif)
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(" and ")
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
            .with_inner_size(PhysicalSize::new(self.scene.args.frame_output.width, self.scene.args.frame_output.height))
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
        if self.scene.recorder.camera().size() != (size.width, size.height) {
            self.scene.resize(size.width, size.height)?;
        }
        let frame = self.scene.newer();
        if frame.is_some() || self.scene.drawn.is_none() {
            self.scene.draw(frame.as_ref())?;
        }
        surface.resize(w, h).map_err(|e| anyhow::anyhow!("resize the window buffer: {e}"))?;
        let mut buffer = surface.buffer_mut().map_err(|e| anyhow::anyhow!("window buffer: {e}"))?;
        let image = self.scene.recorder.drawn();
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
