//! `smlworld mock-mocap`: a mock Qualisys motion-capture server streaming scripted trajectories.

use std::io::Write as _;
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::path::PathBuf;

use anyhow::Context as _;
use smlworld::io::mock_mocap::{DEFAULT_MOCK_RATE_HZ, MocapScript, MockMocapConfig, MockMocapServer};
use smlworld::io::qualisys::DEFAULT_QTM_PORT;

/// Arguments of `smlworld mock-mocap`.
#[derive(Debug, clap::Args)]
pub struct MockMocapArgs {
    /// TCP port to listen on (loopback); 0 picks a free one.
    #[arg(long, default_value_t = DEFAULT_QTM_PORT)]
    pub port: u16,
    /// Number of bodies driving around circles on the lab floor (ignored with --script).
    #[arg(long, default_value_t = 2, value_parser = super::range::count::<u32>(1, u64::from(smlworld::io::mock_mocap::MAX_MOCK_BODIES)))]
    pub bodies: u32,
    /// Capture rate [Hz]: how fast frame numbers advance.
    #[arg(long, default_value_t = DEFAULT_MOCK_RATE_HZ, value_parser = super::range::rate_hz)]
    pub rate: f64,
    /// Keyframe script (CSV: t_s,body,x_mm,y_mm,z_mm,roll_deg,pitch_deg,yaw_deg; bodies numbered
    /// from 1, as in QTM) instead of circles.
    #[arg(long, conflicts_with = "scenario")]
    pub script: Option<PathBuf>,
    /// Drive the real vehicles (id >= 0) of this scenario along their routes at their speeds,
    /// body k = vehicle k, as its `[lab] mocap = { mock = true }` would.
    #[arg(long)]
    pub scenario: Option<PathBuf>,
}

/// Serve until the process is stopped (Ctrl-C).
pub fn main(args: MockMocapArgs) -> anyhow::Result<()> {
    let script = match (&args.script, &args.scenario) {
        (Some(path), _) => MocapScript::load(path)?,
        (None, Some(path)) => smlworld::app::running::scenario::scenario_script(&smlworld::app::Scenario::load(path)?)?,
        (None, None) => MocapScript::circles(args.bodies),
    };
    let bodies = script.body_count();
    let config = MockMocapConfig {
        bind: SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, args.port)),
        rate_hz: args.rate,
        script,
    };
    let server = MockMocapServer::start(config)?;
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "mock Qualisys server listening on {} ({bodies} bodies, {} Hz); Ctrl-C stops it",
        server.local_addr(),
        args.rate
    )
    .and_then(|()| out.flush())
    .context("writing to stdout")?;
    drop(out);
    loop {
        std::thread::park();
    }
}
