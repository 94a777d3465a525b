//! QTM client: a background thread that connects, handshakes, polls `GetCurrentFrame` and
//! reconnects after failures, handing parsed frames over a bounded queue.

use std::io::{Read, Write};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::tracker::Tracker;
use super::wire::{
    DataFrame, MAX_PACKET_LEN, POLL_COMMAND, Packet, PacketDecoder, PacketType, QtmError, VERSION_COMMAND,
    encode_command, parse_data,
};
use crate::io::{WarnLimiter, lock};

/// Default QTM real-time port.
pub const DEFAULT_QTM_PORT: u16 = 22224;
/// Default server address: loopback, port 22224.
pub const DEFAULT_QTM_ADDR: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, DEFAULT_QTM_PORT));
/// Default polling rate of `GetCurrentFrame` \[Hz\] (the 2015 rate).
pub const DEFAULT_POLL_RATE_HZ: f64 = 24.0;

/// Settings of a [`QtmClient`].
#[derive(Debug, Clone, PartialEq)]
pub struct QtmClientConfig {
    /// QTM server (default 127.0.0.1:22224).
    pub addr: SocketAddr,
    /// `GetCurrentFrame` polls per second \[Hz\] (default 24; raising it lowers latency).
    pub poll_rate_hz: f64,
    /// When set, `TakeControl <password>` is sent before `New` (needed when not master).
    pub password: Option<String>,
    /// Wait before reconnecting after a failure (default 1 s).
    pub reconnect_delay: Duration,
    /// Longest wait for a handshake reply or a connection (default 2 s).
    pub handshake_timeout: Duration,
    /// Bound on a packet's size field \[bytes\] (default 1 MiB).
    pub max_packet_len: usize,
}

impl Default for QtmClientConfig {
    fn default() -> Self {
        Self {
            addr: DEFAULT_QTM_ADDR,
            poll_rate_hz: DEFAULT_POLL_RATE_HZ,
            password: None,
            reconnect_delay: Duration::from_secs(1),
            handshake_timeout: Duration::from_secs(2),
            max_packet_len: MAX_PACKET_LEN,
        }
    }
}

/// A frame with the instant it arrived.
#[derive(Debug, Clone, PartialEq)]
pub struct TimedFrame {
    /// When the client received it.
    pub received_at: Instant,
    /// The parsed frame.
    pub frame: DataFrame,
}

/// Counters of a client's life.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct QtmStats {
    /// Whether a session is established now.
    pub connected: bool,
    /// Sessions established (handshake done).
    pub sessions: u64,
    /// Data frames parsed and handed over.
    pub frames: u64,
    /// Packets dropped as malformed (bad data, unknown type, bad size).
    pub bad_packets: u64,
    /// Error packets (type 0) received from the server.
    pub error_replies: u64,
    /// The last problem seen, if any.
    pub last_error: Option<String>,
}

/// Frames waiting in the client's queue at most; older ones are dropped when it is full.
const FRAME_QUEUE: usize = 256;
/// Read timeout of the client socket: bounds how late a poll or a stop request can be.
const CLIENT_TICK: Duration = Duration::from_millis(5);

/// A QTM client running on a background thread: connects, handshakes, polls frames, reconnects
/// after failures. Dropping it stops the thread.
#[derive(Debug)]
pub struct QtmClient {
    frames: Receiver<TimedFrame>,
    stats: Arc<Mutex<QtmStats>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl QtmClient {
    /// Start the client thread (it connects in the background and keeps retrying).
    pub fn spawn(config: QtmClientConfig) -> Result<Self, QtmError> {
        if poll_period(config.poll_rate_hz).is_none() {
            return Err(QtmError::Config(format!(
                "poll rate {} Hz must be a positive number of at most 1e6",
                config.poll_rate_hz
            )));
        }
        let (tx, frames) = std::sync::mpsc::sync_channel(FRAME_QUEUE);
        let stats = Arc::new(Mutex::new(QtmStats::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (stats, stop) = (stats.clone(), stop.clone());
            std::thread::Builder::new()
                .name("qtm-client".into())
                .spawn(move || client_loop(&config, &tx, &stats, &stop))
                .map_err(|source| QtmError::Io { what: "spawn client thread".into(), source })?
        };
        Ok(Self { frames, stats, stop, thread: Some(thread) })
    }

    /// The next received frame, if any (non-blocking).
    pub fn try_next(&self) -> Option<TimedFrame> {
        self.frames.try_recv().ok()
    }

    /// Wait up to `timeout` for the next frame.
    pub fn next_timeout(&self, timeout: Duration) -> Option<TimedFrame> {
        self.frames.recv_timeout(timeout).ok()
    }

    /// Feed every frame received so far into `tracker`, then mark bodies unseen for too long as
    /// stale at `now`. Returns the number of frames fed. This is what a plugin's system calls.
    pub fn poll(&self, tracker: &mut Tracker, now: Instant) -> usize {
        let mut n = 0;
        while let Ok(f) = self.frames.try_recv() {
            tracker.update(&f.frame, f.received_at);
            n += 1;
        }
        tracker.refresh(now);
        n
    }

    /// Counters so far.
    pub fn stats(&self) -> QtmStats {
        lock(&self.stats).clone()
    }

    /// Whether the client thread is still running (it only ends when dropped).
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }
}

impl Drop for QtmClient {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The period of a rate [Hz], `None` unless the rate is in `(0, 1e6]` with a representable period.
fn poll_period(rate_hz: f64) -> Option<Duration> {
    if rate_hz > 0.0 && rate_hz <= 1e6 { Duration::try_from_secs_f64(1.0 / rate_hz).ok() } else { None }
}

/// Everything a client session needs besides its socket.
struct Session<'a> {
    config: &'a QtmClientConfig,
    tx: &'a SyncSender<TimedFrame>,
    stats: &'a Mutex<QtmStats>,
    stop: &'a AtomicBool,
    decoder: PacketDecoder,
    warn: WarnLimiter,
    buf: Vec<u8>,
}

fn client_loop(config: &QtmClientConfig, tx: &SyncSender<TimedFrame>, stats: &Mutex<QtmStats>, stop: &AtomicBool) {
    let mut session = Session {
        config,
        tx,
        stats,
        stop,
        decoder: PacketDecoder::new(config.max_packet_len),
        warn: WarnLimiter::new(Duration::from_secs(1)),
        buf: vec![0; 64 * 1024],
    };
    let mut connect_warn = WarnLimiter::new(Duration::from_secs(10));
    while !stop.load(Ordering::Relaxed) {
        let result = TcpStream::connect_timeout(&config.addr, config.handshake_timeout)
            .map_err(|source| QtmError::Io { what: format!("connect to {}", config.addr), source })
            .and_then(|stream| {
                session.decoder.reset();
                session.run(stream)
            });
        lock(stats).connected = false;
        match result {
            Ok(()) => return,
            Err(e) => {
                connect_warn.warn(&format!("QTM client: {e}; retrying in {:?}", config.reconnect_delay));
                lock(stats).last_error = Some(e.to_string());
            }
        }
        let until = Instant::now() + config.reconnect_delay;
        while !stop.load(Ordering::Relaxed) && Instant::now() < until {
            std::thread::sleep(CLIENT_TICK.min(config.reconnect_delay));
        }
    }
}

impl Session<'_> {
    /// One connection: handshake then poll until stopped (Ok) or the stream breaks (Err).
    fn run(&mut self, mut stream: TcpStream) -> Result<(), QtmError> {
        let io = |what: &str| {
            let what = what.to_string();
            move |source| QtmError::Io { what, source }
        };
        stream.set_nodelay(true).map_err(io("set nodelay"))?;
        stream.set_read_timeout(Some(CLIENT_TICK)).map_err(io("set read timeout"))?;
        self.command(&mut stream, VERSION_COMMAND, true)?;
        if let Some(pw) = &self.config.password {
            let take = format!("TakeControl {pw}");
            self.command(&mut stream, &take, false)?;
        }
        self.command(&mut stream, "New", false)?;
        {
            let mut s = lock(self.stats);
            s.connected = true;
            s.sessions += 1;
        }
        tracing::info!("QTM client: connected to {}", self.config.addr);
        let period = poll_period(self.config.poll_rate_hz).unwrap_or(Duration::from_secs(1));
        let poll = encode_command(POLL_COMMAND);
        let mut next_poll = Instant::now();
        while !self.stop.load(Ordering::Relaxed) {
            let now = Instant::now();
            if now >= next_poll {
                stream.write_all(&poll).map_err(io("send GetCurrentFrame"))?;
                next_poll += period;
                if next_poll < now {
                    next_poll = now + period;
                }
            }
            // Packets already buffered first: an EOF must not hide them.
            while let Some(p) = self.decoder.next_packet() {
                self.handle(p)?;
            }
            self.read_some(&mut stream)?;
        }
        Ok(())
    }

    /// Read what is available (up to one read timeout) into the decoder.
    fn read_some(&mut self, stream: &mut TcpStream) -> Result<(), QtmError> {
        match stream.read(&mut self.buf) {
            Ok(0) => Err(QtmError::Closed),
            Ok(n) => {
                self.decoder.push(&self.buf[..n]);
                Ok(())
            }
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(()),
            Err(source) => Err(QtmError::Io { what: "read".into(), source }),
        }
    }

    /// Send a handshake command and wait for its reply (skipping the server's greeting and
    /// other packets). An error reply is fatal when `required`, else a warning.
    fn command(&mut self, stream: &mut TcpStream, text: &str, required: bool) -> Result<(), QtmError> {
        stream
            .write_all(&encode_command(text))
            .map_err(|source| QtmError::Io { what: format!("send `{text}`"), source })?;
        let deadline = Instant::now() + self.config.handshake_timeout;
        while Instant::now() < deadline && !self.stop.load(Ordering::Relaxed) {
            while let Some(p) = self.decoder.next_packet() {
                let p = match p {
                    Ok(p) => p,
                    Err(e @ QtmError::BadSize { .. }) => return Err(e),
                    Err(e) => {
                        self.bad_packet(&e);
                        continue;
                    }
                };
                let reply = p.text();
                match p.kind {
                    PacketType::Command if reply.starts_with("QTM RT Interface connected") => {}
                    PacketType::Command => {
                        tracing::debug!("QTM `{text}` -> `{reply}`");
                        return Ok(());
                    }
                    PacketType::Error if required => {
                        return Err(QtmError::Handshake(format!("`{text}` refused: {reply}")));
                    }
                    PacketType::Error => {
                        lock(self.stats).error_replies += 1;
                        tracing::warn!("QTM `{text}` refused: {reply}; continuing");
                        return Ok(());
                    }
                    _ => {}
                }
            }
            self.read_some(stream)?;
        }
        Err(QtmError::Handshake(format!("no reply to `{text}` within {:?}", self.config.handshake_timeout)))
    }

    fn handle(&mut self, p: Result<Packet, QtmError>) -> Result<(), QtmError> {
        let p = match p {
            Ok(p) => p,
            Err(e @ QtmError::BadSize { .. }) => {
                lock(self.stats).bad_packets += 1;
                return Err(e);
            }
            Err(e) => {
                self.bad_packet(&e);
                return Ok(());
            }
        };
        match p.kind {
            PacketType::Data => match parse_data(&p.payload) {
                Ok(frame) => {
                    lock(self.stats).frames += 1;
                    let timed = TimedFrame { received_at: Instant::now(), frame };
                    if let Err(TrySendError::Full(_)) = self.tx.try_send(timed) {
                        tracing::debug!("QTM client: frame queue full, frame dropped");
                    }
                }
                Err(e) => self.bad_packet(&e),
            },
            PacketType::Error => {
                let text = p.text();
                let mut s = lock(self.stats);
                s.error_replies += 1;
                s.last_error = Some(format!("QTM error reply: {text}"));
                drop(s);
                self.warn.warn(&format!("QTM error reply: {text}"));
            }
            PacketType::NoMoreData => tracing::debug!("QTM: no more data"),
            other => tracing::debug!("QTM: ignoring {other:?} packet"),
        }
        Ok(())
    }

    fn bad_packet(&mut self, e: &QtmError) {
        let mut s = lock(self.stats);
        s.bad_packets += 1;
        s.last_error = Some(e.to_string());
        drop(s);
        self.warn.warn(&format!("QTM client: dropped packet: {e}"));
    }
}
