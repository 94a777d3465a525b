//! UDP ends of the visualisation stream: a rate-limited sender and a receiver thread that keeps
//! the newest complete frame.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::codec::{VizEncoder, VizError, VizLight, VizVehicle, encode_lights};
use super::reassembly::{VizFrame, VizReassembler, VizStats};
use crate::io::lock;

/// Default destination of the stream: loopback, port 38008 (the 2015 port).
pub const DEFAULT_VIZ_ADDR: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 38008));
/// Default send rate \[Hz\] (the 2015 rate).
pub const DEFAULT_VIZ_RATE_HZ: f64 = 50.0;

/// Settings of a [`VizSender`].
#[derive(Debug, Clone, PartialEq)]
pub struct VizSenderConfig {
    /// Where datagrams go (default 127.0.0.1:38008).
    pub target: SocketAddr,
    /// Local address to send from; `None` (default): loopback, any port, for a loopback target,
    /// else the unspecified address of the target's family.
    pub bind: Option<SocketAddr>,
    /// Frames per second \[Hz\] for [`VizSender::send_if_due`] (default 50; raising it sends more often).
    pub rate_hz: f64,
}

impl Default for VizSenderConfig {
    fn default() -> Self {
        Self { target: DEFAULT_VIZ_ADDR, bind: None, rate_hz: DEFAULT_VIZ_RATE_HZ }
    }
}

/// Sends frames of the visualisation stream over UDP; the counter starts at 0.
#[derive(Debug)]
pub struct VizSender {
    socket: UdpSocket,
    target: SocketAddr,
    encoder: VizEncoder,
    /// Datagrams of the last [`VizSender::send_lights`].
    lights_buf: Vec<Vec<u8>>,
    counter: u64,
    period_us: i64,
    next_due_us: Option<i64>,
}

impl VizSender {
    /// Bind the sending socket.
    pub fn new(config: &VizSenderConfig) -> Result<Self, VizError> {
        if !(config.rate_hz > 0.0 && config.rate_hz <= 1e6) {
            return Err(VizError::BadRate(config.rate_hz));
        }
        let bind = config.bind.unwrap_or_else(|| match config.target.ip() {
            ip if ip.is_loopback() => SocketAddr::new(ip, 0),
            IpAddr::V4(_) => SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), 0),
            IpAddr::V6(_) => SocketAddr::new(IpAddr::V6(Ipv6Addr::UNSPECIFIED), 0),
        });
        let socket = UdpSocket::bind(bind).map_err(|source| VizError::Io { what: format!("bind {bind}"), source })?;
        Ok(Self {
            socket,
            target: config.target,
            encoder: VizEncoder::new(),
            lights_buf: Vec::new(),
            counter: 0,
            period_us: ((1e6 / config.rate_hz).round() as i64).max(1),
            next_due_us: None,
        })
    }

    /// Send one frame now (one or more datagrams); returns the number of datagrams sent.
    /// The counter advances even when sending fails, so a receiver never sees a reused counter.
    pub fn send(&mut self, vehicles: &[VizVehicle]) -> Result<usize, VizError> {
        let counter = self.counter;
        self.counter += 1;
        let parts = self.encoder.encode(counter, vehicles);
        for part in parts {
            self.socket
                .send_to(part, self.target)
                .map_err(|source| VizError::Io { what: format!("send to {}", self.target), source })?;
        }
        Ok(parts.len())
    }

    /// Send the states of `lights` for the next frame (the lights extension: call it just
    /// before [`VizSender::send`]; the counter does not advance); returns the number of
    /// datagrams sent (none for no lights).
    pub fn send_lights(&mut self, lights: &[VizLight]) -> Result<usize, VizError> {
        encode_lights(self.counter, lights, &mut self.lights_buf);
        for datagram in &self.lights_buf {
            self.socket
                .send_to(datagram, self.target)
                .map_err(|source| VizError::Io { what: format!("send to {}", self.target), source })?;
        }
        Ok(self.lights_buf.len())
    }

    /// Send a frame if one period (1 / rate) has passed since the last one sent by this method,
    /// `now_us` being the caller's clock \[µs\] (sim or wall time). Returns whether it sent.
    pub fn send_if_due(&mut self, now_us: i64, vehicles: &[VizVehicle]) -> Result<bool, VizError> {
        if self.next_due_us.is_some_and(|due| now_us < due) {
            return Ok(false);
        }
        let base = self.next_due_us.unwrap_or(now_us);
        // Keep a fixed cadence; after a long pause, restart from now instead of bursting.
        let start = if now_us.saturating_sub(base) >= self.period_us { now_us } else { base };
        self.next_due_us = Some(start.saturating_add(self.period_us));
        self.send(vehicles)?;
        Ok(true)
    }

    /// Counter the next frame will carry.
    pub fn next_counter(&self) -> u64 {
        self.counter
    }

    /// Period between frames for [`Self::send_if_due`] \[µs\].
    pub fn period_us(&self) -> i64 {
        self.period_us
    }
}

#[derive(Debug, Default)]
struct Shared {
    latest: Option<VizFrame>,
    stats: VizStats,
}

/// Receives the visualisation stream on a background thread; keeps the newest complete frame.
/// Bad datagrams are counted and logged, never fatal. Dropping the receiver stops the thread.
#[derive(Debug)]
pub struct VizReceiver {
    shared: Arc<(Mutex<Shared>, Condvar)>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    local_addr: SocketAddr,
}

/// How often the receiving thread checks whether it should stop.
const RECV_POLL: Duration = Duration::from_millis(50);

impl VizReceiver {
    /// Bind `addr` (e.g. 127.0.0.1:38008, or port 0 for any) and start receiving.
    pub fn bind(addr: SocketAddr) -> Result<Self, VizError> {
        let io = |what: String| move |source| VizError::Io { what, source };
        let socket = bind_with_big_buffer(addr).map_err(io(format!("bind {addr}")))?;
        socket.set_read_timeout(Some(RECV_POLL)).map_err(io("set read timeout".into()))?;
        let local_addr = socket.local_addr().map_err(io("local address".into()))?;
        let shared = Arc::new((Mutex::new(Shared::default()), Condvar::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (shared, stop) = (shared.clone(), stop.clone());
            std::thread::Builder::new()
                .name("viz-receiver".into())
                .spawn(move || receive_loop(&socket, &shared, &stop))
                .map_err(io("spawn receiver thread".into()))?
        };
        Ok(Self { shared, stop, thread: Some(thread), local_addr })
    }

    /// The address actually bound (useful with port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// The newest complete frame, if any.
    pub fn latest(&self) -> Option<VizFrame> {
        lock(&self.shared.0).latest.clone()
    }

    /// Wait up to `timeout` for a frame with a counter newer than `after` (`None`: any frame).
    pub fn wait_newer(&self, after: Option<u64>, timeout: Duration) -> Option<VizFrame> {
        let deadline = Instant::now() + timeout;
        let mut guard = lock(&self.shared.0);
        loop {
            if let Some(f) = &guard.latest
                && after.is_none_or(|a| f.counter > a)
            {
                return Some(f.clone());
            }
            let left = deadline.checked_duration_since(Instant::now())?;
            guard = match self.shared.1.wait_timeout(guard, left) {
                Ok((g, _)) => g,
                Err(poisoned) => poisoned.into_inner().0,
            };
        }
    }

    /// Counters of what was received.
    pub fn stats(&self) -> VizStats {
        lock(&self.shared.0).stats
    }

    /// Whether the receiving thread is still running.
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }
}

impl Drop for VizReceiver {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Receive buffer asked for \[bytes\]: a split frame arrives as a burst of up to hundreds of
/// datagrams, more than the usual 208 KiB default holds. The kernel may grant less.
pub const RECV_BUFFER_LEN: usize = 4 << 20;

/// Bind a UDP socket with a receive buffer of [`RECV_BUFFER_LEN`] (or what the system allows).
fn bind_with_big_buffer(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    use socket2::{Domain, Protocol, Socket, Type};
    let socket = Socket::new(Domain::for_address(addr), Type::DGRAM, Some(Protocol::UDP))?;
    if let Err(e) = socket.set_recv_buffer_size(RECV_BUFFER_LEN) {
        tracing::warn!("visualisation receiver: cannot enlarge the receive buffer ({e}); big frames may be lost");
    }
    socket.bind(&addr.into())?;
    Ok(socket.into())
}

fn receive_loop(socket: &UdpSocket, shared: &(Mutex<Shared>, Condvar), stop: &AtomicBool) {
    // Bigger than MAX_DATAGRAM_LEN so datagrams from newer senders are read whole.
    let mut buf = vec![0u8; 65536];
    let mut reassembler = VizReassembler::new();
    while !stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buf) {
            Ok((n, _)) => {
                let frame = reassembler.push_bytes(&buf[..n]);
                let mut s = lock(&shared.0);
                s.stats = reassembler.stats();
                if let Some(f) = frame {
                    s.latest = Some(f);
                    shared.1.notify_all();
                }
            }
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(e) => {
                tracing::warn!("visualisation receiver: {e}");
                std::thread::sleep(RECV_POLL);
            }
        }
    }
}
