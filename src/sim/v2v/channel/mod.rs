//! V2V channel models: which receptions are lost and how late the others arrive, as a pure,
//! seeded function of the link, the round and the distance (DESIGN "Lanes, traffic and chance";
//! REFERENCE "Channels").
//!
//! - Bernoulli loss: each reception lost with probability `p` (Plexe's frame error rate).
//! - Distance loss: `p(d) = p_at_0 + (p_at_range - p_at_0) · (d / range)²`, clamped to [0, 1]: the
//!   delivery ratio falls off slowly near the sender and fastest at the edge of the range, the
//!   shape of a log-distance path loss at the ranges V2V uses (a quadratic fit; measured links
//!   stay above 90 % to 45-70 m).
//! - Gilbert-Elliott bursts, per link: a two-state Markov chain stepped once per message on the
//!   link, good -> bad with `p_enter`, bad -> good with `p_leave`; in the bad state a reception is
//!   lost with `loss_in_burst`. Stationary share in bad `p_enter / (p_enter + p_leave)`, mean
//!   burst length `1 / p_leave` messages.
//! - Delay: `delay_ms` plus uniform `[0, jitter_ms)`; a link never reorders (a message is never
//!   due before the one sent before it on the same link).
//!
//! - A model of a plugin's ([`ChannelLossModel`], registered by name in [`plugins`]): whatever its
//!   [`ChannelLossModel::deliver`] decides, per reception.
//!
//! Every draw is [`crate::sim::random::uniform`] keyed by (seed, channel stream, link, round, message
//! index, draw), so results do not depend on threads or system order and a draw allocates nothing.
//!
//! The files: this one the runtime form every channel runs ([`ChannelModel`]: loss, bursts,
//! delay, the draws' keys); `plugins` the trait a model implements ([`ChannelLossModel`]) and
//! the registry of names; the built-in models one file each: `constant` ([`ConstantLoss`]),
//! `distance` ([`DistanceLoss`]), `gilbert_elliott` ([`GilbertElliott`]).

use crate::sim::random::{key, mix, uniform_at};
use crate::world::VehicleId;

mod constant;
mod distance;
mod gilbert_elliott;
pub mod plugins;

pub use constant::ConstantLoss;
pub use distance::DistanceLoss;
pub use gilbert_elliott::GilbertElliott;
pub use plugins::{ChannelLossModel, LinkContext, LossModel, PluginLoss};

/// Probability that a reception is lost, before bursts.
#[derive(Debug, Clone, PartialEq)]
pub enum Loss {
    /// The same probability at every distance [-].
    Constant(f64),
    /// Rising with distance: `p_at_0 + (p_at_range - p_at_0) (d / range)²` [-].
    Distance {
        /// Loss probability next to the sender [-].
        p_at_0: f64,
        /// Loss probability at the channel's range [-].
        p_at_range: f64,
    },
    /// A model registered by a plugin ([`crate::sim::SimBuilder::register_channel_model`]):
    /// it decides each reception's fate itself.
    Plugin(PluginLoss),
}

impl Default for Loss {
    fn default() -> Self {
        Loss::Constant(0.0)
    }
}

/// Gilbert-Elliott burst loss, per link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Burst {
    /// Probability per message of going from the good to the bad state [-].
    pub p_enter: f64,
    /// Probability per message of leaving the bad state [-]; mean burst length is `1 / p_leave`.
    pub p_leave: f64,
    /// Loss probability in the bad state [-].
    pub loss_in_burst: f64,
}

/// One channel's model.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ChannelModel {
    /// Loss before bursts.
    pub loss: Loss,
    /// Gilbert-Elliott bursts, if any.
    pub burst: Option<Burst>,
    /// Fixed delivery delay \[ms\].
    pub delay_ms: f64,
    /// Extra delay, uniform in `[0, jitter_ms)` \[ms\].
    pub jitter_ms: f64,
}

/// Per-link state a channel keeps between messages: the burst state, a plugin model's word and
/// the latest due time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LinkState {
    /// In the Gilbert-Elliott bad state.
    pub bad: bool,
    /// A plugin model's state of this link (0 on a fresh link), kept by the runtime when the
    /// model asks for it ([`ChannelLossModel::keeps_link_state`]).
    pub word: u64,
    /// Due time of the last message delivered on the link \[µs\], so none overtakes it.
    pub last_due_us: u64,
}

/// Which message on which link in which round: the counter every draw is keyed by.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Draw {
    /// The scenario's seed.
    pub seed: u64,
    /// Which channel (or sensor) draws: a fixed number per stream.
    pub stream: u64,
    /// Sender id.
    pub sender: i32,
    /// Receiver id.
    pub receiver: i32,
    /// Round number of the channel.
    pub round: u64,
    /// Index of the message among the sender's messages of the round.
    pub index: u32,
}

impl Draw {
    /// A uniform number in [0, 1) for draw number `k` of this message.
    pub fn uniform(&self, k: u64) -> f64 {
        uniform_at(self.key(), (u64::from(self.index) << 8) | k)
    }

    /// The counter of this link's round, shared by every message of it:
    /// `uniform_at(draw.key(), (index << 8) | k) == draw.uniform(k)`. It is
    /// [`link_key`]`(`[`round_key`]`(seed, stream, round), sender, receiver)`: a round's key once,
    /// then one hash per link, one per draw.
    pub fn key(&self) -> u64 {
        link_key(round_key(self.seed, self.stream, self.round), self.sender, self.receiver)
    }
}

/// The key of one round of a channel's stream, shared by all its links ([`Draw::key`]).
pub fn round_key(seed: u64, stream: u64, round: u64) -> u64 {
    key(seed, stream, round)
}

/// The key of the link (sender, receiver) in the round whose key is `round` ([`round_key`]):
/// one hash of the pair's 64 bits xored with the round's key. The round's key is itself a hash
/// of (seed, stream, round), so distinct links of a round hash distinct inputs and no pair of
/// rounds lines up (REFERENCE "Channels": keyed by seed, stream, sender, receiver and round).
/// One hash rather than two: a lossy wifi round makes one link key per reception.
#[inline]
pub fn link_key(round: u64, sender: i32, receiver: i32) -> u64 {
    mix(((u64::from(sender as u32) << 32) | u64::from(receiver as u32)) ^ round)
}

/// `x.round() as u64` for the delays (non-negative; a NaN or negative gives 0 as there) without
/// a library call: the processors this is built for have no rounding instruction in the
/// baseline instruction set, and `round` was a per-reception call.
#[inline]
fn round_us(x: f64) -> u64 {
    // Through i64, whose conversions are single instructions (u64's are branchy sequences).
    let t = x as i64;
    (t + i64::from(x - t as f64 >= 0.5)).max(0) as u64
}

impl ChannelModel {
    /// Whether nothing is ever lost or delayed (the fast path: no draws, no link state).
    pub fn is_perfect(&self) -> bool {
        self.loss_free() && self.delay_ms == 0.0 && self.jitter_ms == 0.0
    }

    /// Whether nothing is ever lost.
    pub fn loss_free(&self) -> bool {
        let no_loss = match &self.loss {
            Loss::Constant(p) => *p == 0.0,
            Loss::Distance { p_at_0, p_at_range } => *p_at_0 == 0.0 && *p_at_range == 0.0,
            Loss::Plugin(_) => false,
        };
        no_loss && self.burst.is_none_or(|b| b.loss_in_burst == 0.0 || b.p_enter == 0.0)
    }

    /// Whether messages may be delayed.
    pub fn delays(&self) -> bool {
        self.delay_ms > 0.0 || self.jitter_ms > 0.0 || matches!(&self.loss, Loss::Plugin(m) if m.delays())
    }

    /// Whether a link's state matters: bursts step it, delays order by it. Without either,
    /// [`ChannelModel::deliver`] may be given a fresh [`LinkState`] and nothing is kept per link.
    pub fn keeps_link_state(&self) -> bool {
        self.steps_links() || self.delays()
    }

    /// Whether a message changes its link's state for the next one: bursts do, and a plugin
    /// model that keeps a word per link.
    pub fn steps_links(&self) -> bool {
        self.burst.is_some() || matches!(&self.loss, Loss::Plugin(m) if m.keeps_link_state())
    }

    /// The widest spread of the delays \[µs\]: the largest delay [`ChannelModel::deliver`] gives
    /// less the smallest. Rounds further apart than this cannot overtake one another. A plugin
    /// model's delays are not bounded in advance: every round may overtake.
    pub fn delay_spread_us(&self) -> u64 {
        if matches!(&self.loss, Loss::Plugin(m) if m.delays()) {
            return u64::MAX;
        }
        let us = |ms: f64| round_us(ms * 1000.0);
        us(self.delay_ms + self.jitter_ms.max(0.0)).saturating_sub(us(self.delay_ms))
    }

    /// Whether the loss depends on the distance.
    pub fn uses_distance(&self) -> bool {
        match &self.loss {
            Loss::Distance { .. } => true,
            Loss::Plugin(m) => m.uses_distance(),
            Loss::Constant(_) => false,
        }
    }

    /// Loss probability before bursts at `distance` \[m\] for a channel of `range` \[m\].
    /// A plugin model decides in [`ChannelModel::deliver`]: 0 here.
    pub fn loss_at(&self, distance: f64, range: f64) -> f64 {
        match self.loss {
            Loss::Constant(p) => p,
            Loss::Distance { p_at_0, p_at_range } => {
                let u = if range > 0.0 { (distance / range).min(1.0) } else { 1.0 };
                (p_at_0 + (p_at_range - p_at_0) * u * u).clamp(0.0, 1.0)
            }
            Loss::Plugin(_) => 0.0,
        }
    }

    /// The fate of one reception: `None` when lost, else its delay \[µs\] (never due before the
    /// link's previous message: `link.last_due_us` is kept). `now_us` is the round's time,
    /// `distance` \[m\] the sender-receiver distance, `range` \[m\] the channel's range.
    pub fn deliver(&self, draw: &Draw, now_us: u64, distance: f64, range: f64, link: &mut LinkState) -> Option<u64> {
        let ids = (VehicleId(draw.sender), VehicleId(draw.receiver));
        self.deliver_keyed(draw.key(), draw.index, ids, now_us, distance, range, link)
    }

    /// [`ChannelModel::deliver`] of message `index` of the link round whose counter is
    /// `key` ([`Draw::key`]): the same fate, for one hash per draw. Loss and jitter share one
    /// draw, `mix(key ^ ((index << 8) | 2))` ([`uniform_at`]'s hash), or for the link's first
    /// message of the round (index 0, the common one: a beacon a round) `key` itself, already a
    /// hash of (seed, stream, round, sender, receiver) that nothing else draws from: its high 32
    /// bits decide the loss, its low 32 bits the jitter (each a uniform of 2⁻³² resolution,
    /// finer than a microsecond of jitter), so a lossy, jittered beacon costs its link's hash
    /// and nothing more ([`ChannelModel::fate`]). `ids` are (sender, receiver), which a plugin
    /// model is told; a plugin model's own word is `mix(key ^ ((index << 8) | 3))`.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn deliver_keyed(
        &self,
        key: u64,
        index: u32,
        ids: (VehicleId, VehicleId),
        now_us: u64,
        distance: f64,
        range: f64,
        link: &mut LinkState,
    ) -> Option<u64> {
        let draw = |k: u64| uniform_at(key, (u64::from(index) << 8) | k);
        if let Some(b) = self.burst {
            let flip = draw(0);
            link.bad = if link.bad { flip >= b.p_leave } else { flip < b.p_enter };
            if link.bad && draw(1) < b.loss_in_burst {
                return None;
            }
        }
        let delay_us = match &self.loss {
            Loss::Plugin(model) => {
                let (sender, receiver) = ids;
                let random = mix(key ^ ((u64::from(index) << 8) | 3));
                let context = LinkContext { sender, receiver, distance, range, now_us, random };
                let extra_ms = model.deliver(&context, &mut link.word)?;
                let extra_us = if model.delays() { round_us(extra_ms * 1000.0) } else { 0 };
                self.fate(key, index, 0.0)? + extra_us
            }
            _ => self.fate(key, index, self.loss_at(distance, range))?,
        };
        let due = (now_us + delay_us).max(link.last_due_us);
        link.last_due_us = due;
        Some(due - now_us)
    }

    /// The loss and delay of message `index` of the link round `key` after its burst state:
    /// `None` when lost with probability `p` ([`ChannelModel::loss_at`]), else its delay \[µs\]
    /// before the link's ordering. What [`ChannelModel::deliver_keyed`] gives for a model
    /// without bursts and a fresh link, so a round of such a model (nothing kept per link) calls
    /// this directly: one hash and a few operations per reception, inlined.
    #[inline]
    pub fn fate(&self, key: u64, index: u32, p: f64) -> Option<u64> {
        let (lossy, jittered) = (p > 0.0, self.jitter_ms > 0.0);
        let bits = match (lossy || jittered, index) {
            (false, _) => 0,
            (true, 0) => key,
            (true, _) => mix(key ^ ((u64::from(index) << 8) | 2)),
        };
        const HALF: f64 = 1.0 / 4_294_967_296.0;
        // Through u32: its conversion to f64 is one instruction, a u64's a branchy sequence.
        if lossy && f64::from((bits >> 32) as u32) * HALF < p {
            return None;
        }
        let jitter = if jittered { f64::from(bits as u32) * HALF * self.jitter_ms } else { 0.0 };
        Some(round_us((self.delay_ms + jitter) * 1000.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn draw(round: u64) -> Draw {
        Draw { seed: 7, stream: 1, sender: -1, receiver: -2, round, index: 0 }
    }

    /// Delivered share over `n` messages on one link.
    fn delivered(model: &ChannelModel, n: u64) -> (f64, Vec<u64>) {
        let mut link = LinkState::default();
        let mut bursts = Vec::new();
        let mut run = 0;
        let mut ok = 0;
        for r in 0..n {
            match model.deliver(&draw(r), r * 100_000, 10.0, 50.0, &mut link) {
                Some(_) => {
                    ok += 1;
                    if run > 0 {
                        bursts.push(run);
                    }
                    run = 0;
                }
                None => run += 1,
            }
        }
        (ok as f64 / n as f64, bursts)
    }

    #[test]
    fn bernoulli_loss_delivers_one_minus_p() {
        for p in [0.0, 0.1, 0.5] {
            let m = ChannelModel { loss: Loss::Constant(p), ..Default::default() };
            let (share, _) = delivered(&m, 20_000);
            assert!((share - (1.0 - p)).abs() < 0.02, "p {p}: delivered {share}");
        }
    }

    #[test]
    fn gilbert_elliott_has_its_stationary_loss_and_burst_length() {
        let b = Burst { p_enter: 0.01, p_leave: 0.2, loss_in_burst: 1.0 };
        let m = ChannelModel { burst: Some(b), ..Default::default() };
        let (share, bursts) = delivered(&m, 200_000);
        let expected_loss = b.p_enter / (b.p_enter + b.p_leave) * b.loss_in_burst;
        assert!(((1.0 - share) - expected_loss).abs() < 0.1 * expected_loss, "loss {} vs {expected_loss}", 1.0 - share);
        let mean = bursts.iter().sum::<u64>() as f64 / bursts.len() as f64;
        assert!((mean - 1.0 / b.p_leave).abs() < 0.1 / b.p_leave, "mean burst {mean} vs {}", 1.0 / b.p_leave);
    }

    #[test]
    fn distance_loss_rises_to_its_value_at_the_range() {
        let m = ChannelModel { loss: Loss::Distance { p_at_0: 0.01, p_at_range: 0.5 }, ..Default::default() };
        assert!((m.loss_at(0.0, 50.0) - 0.01).abs() < 1e-12);
        assert!((m.loss_at(25.0, 50.0) - (0.01 + 0.49 * 0.25)).abs() < 1e-12);
        assert!((m.loss_at(50.0, 50.0) - 0.5).abs() < 1e-12);
        assert!(m.loss_at(10.0, 50.0) < m.loss_at(40.0, 50.0));
    }

    #[test]
    fn jitter_never_reorders_a_link_and_delay_has_its_mean() {
        let m = ChannelModel { delay_ms: 10.0, jitter_ms: 5.0, ..Default::default() };
        let mut link = LinkState::default();
        let mut last_due = 0;
        let mut sum = 0.0;
        let n = 10_000;
        for r in 0..n {
            // Messages 1 ms apart: jitter would reorder them without the link rule.
            let now = r * 1_000;
            let d = m.deliver(&draw(r), now, 1.0, 50.0, &mut link).expect("no loss configured");
            assert!(now + d >= last_due, "message {r} overtook the one before");
            last_due = now + d;
            sum += d as f64;
        }
        let mean_ms = sum / n as f64 / 1000.0;
        assert!(mean_ms >= 12.5 - 0.2, "mean delay {mean_ms} ms, at least delay + jitter / 2");
    }

    #[test]
    fn loss_and_jitter_from_one_draw_are_independent() {
        // Fresh links (no ordering), many of them: the loss share, and the jitter of the
        // delivered ones uniform over [0, jitter) whatever the loss took.
        let m = ChannelModel { loss: Loss::Constant(0.3), delay_ms: 10.0, jitter_ms: 5.0, burst: None };
        let n = 100_000;
        let delays: Vec<u64> = (0..n)
            .filter_map(|r| {
                let d = Draw { sender: (r % 1000) as i32, receiver: -1 - (r / 1000) as i32, ..draw(r / 7) };
                m.deliver(&d, 1_000_000, 0.0, 50.0, &mut LinkState::default())
            })
            .collect();
        let share = delays.len() as f64 / n as f64;
        assert!((share - 0.7).abs() < 4.0 * (0.21 / n as f64).sqrt(), "delivered {share}");
        assert!(delays.iter().all(|&d| (10_000..=15_000).contains(&d)), "a delay outside 10-15 ms");
        let k = delays.len() as f64;
        for quarter in 1..4 {
            let below = delays.iter().filter(|&&d| d < 10_000 + 1250 * quarter).count() as f64 / k;
            let q = 0.25 * quarter as f64;
            assert!((below - q).abs() < 0.01, "{below} of the jitters below {q} of the range");
        }
    }

    #[test]
    fn the_fate_is_delivers_on_a_fresh_link_without_bursts() {
        for model in [
            ChannelModel { loss: Loss::Constant(0.3), delay_ms: 10.0, jitter_ms: 5.0, burst: None },
            ChannelModel { loss: Loss::Constant(0.0), delay_ms: 0.0, jitter_ms: 2.0, burst: None },
            ChannelModel { loss: Loss::Constant(0.5), ..Default::default() },
        ] {
            for r in 0..2000 {
                let d = Draw { index: (r % 3) as u32, ..draw(r) };
                let fresh = model.deliver(&d, 5_000, 0.0, 50.0, &mut LinkState::default());
                assert_eq!(fresh, model.fate(d.key(), d.index, model.loss_at(0.0, 50.0)), "{model:?} draw {r}");
            }
        }
    }

    #[test]
    fn a_link_rounds_key_draws_what_each_draw_draws() {
        for r in 0..200 {
            let d = Draw { index: (r % 5) as u32, sender: r as i32 - 100, ..draw(r / 3) };
            for k in 0..4 {
                assert_eq!(uniform_at(d.key(), (u64::from(d.index) << 8) | k), d.uniform(k), "draw {r}, {k}");
            }
        }
    }

    #[test]
    fn round_us_rounds_like_round() {
        for x in [0.0, 0.4999999999999999, 0.5, 1.5, 2.5, 12_499.5, 12_500.49, 1e15 + 0.5, -3.0, -0.5, f64::NAN] {
            assert_eq!(round_us(x), x.round() as u64, "{x}");
        }
        for k in 0..100_000u64 {
            let x = k as f64 * 0.137;
            assert_eq!(round_us(x), x.round() as u64, "{x}");
        }
    }

    #[test]
    fn the_delay_spread_is_the_jitter_in_microseconds() {
        let m = ChannelModel { delay_ms: 10.0, jitter_ms: 5.0, ..Default::default() };
        assert_eq!(m.delay_spread_us(), 5000);
        assert_eq!(ChannelModel { jitter_ms: 0.0, ..m }.delay_spread_us(), 0);
    }

    #[test]
    fn draws_differ_by_seed_link_and_round() {
        let a = draw(3);
        let b = Draw { seed: 8, ..a };
        let c = Draw { receiver: -3, ..a };
        let d = Draw { round: 4, ..a };
        assert_eq!(a.uniform(0), draw(3).uniform(0));
        for other in [b, c, d] {
            assert_ne!(a.uniform(0), other.uniform(0));
        }
    }
}
