//! The clock and the multi-rate scheduler: one schedule per module, earliest due first.

use bevy_ecs::prelude::{Resource, Schedule, World};
use bevy_ecs::schedule::{
    InternedScheduleLabel, IntoScheduleConfigs, ScheduleLabel, SingleThreadedExecutor, SystemSet,
};

use crate::world::SimTime;

/// The phases of the simulation as system sets, in the style of bevy's `*Systems` sets: a system
/// says which phase it belongs to with `.in_set(SimSystems::Control)` and orders itself against
/// other phases by set (`.after(SimSystems::Integrate)`), never by naming another plugin's
/// functions. Every module's schedule chains them in this order, so a module that holds systems
/// of several phases (a student's own module, say) still runs them sense -> communicate ->
/// control -> integrate. Between modules the [`Phase`] of each module orders the ticks due at the
/// same instant the same way.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SimSystems {
    /// Sensors and anything that only observes the world.
    Sense,
    /// V2V rounds: out-boxes to in-boxes.
    Communicate,
    /// Controllers: read state, readings and mail; write commands and out-going mail.
    Control,
    /// Dynamics: integrate the models over the step.
    Integrate,
}

/// A module label is already taken.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("a module with schedule label {label} already exists (module `{existing}`): give the new module its own label")]
pub struct DuplicateModule {
    /// The label asked for again.
    pub label: String,
    /// Name of the module that has it.
    pub existing: String,
}

/// Schedule of the sensor module (radar, velodyne, omniscient): [`Phase::Sense`], 20 Hz.
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Sensors;
/// Schedule of the short-range wifi V2V channel: [`Phase::Communicate`], 10 Hz.
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Wifi;
/// Schedule of the long-range network V2V channel: [`Phase::Communicate`], 1 Hz.
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Network;
/// Schedule of the controllers: [`Phase::Control`], 20 Hz. Student controllers go here.
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Control;
/// Schedule of the dynamics models: [`Phase::Dynamics`], 50 Hz.
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Dynamics;

/// Order of modules due at the same instant: sense, then communicate, then control, then dynamics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Phase {
    /// Sensors (and anything that only observes the world, such as logging).
    Sense,
    /// V2V rounds.
    Communicate,
    /// Controllers.
    Control,
    /// Dynamics integration.
    Dynamics,
}

/// Rates of the standard modules \[Hz\]; the defaults are those of the 2015 simulator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rates {
    /// Dynamics integration rate \[Hz\]; raising it shortens the integration step.
    pub dynamics: f64,
    /// Sensor rate \[Hz\].
    pub sensors: f64,
    /// Controller rate \[Hz\].
    pub control: f64,
    /// Wifi round rate \[Hz\].
    pub wifi: f64,
    /// Network round rate \[Hz\].
    pub network: f64,
}

impl Default for Rates {
    fn default() -> Self {
        Rates { dynamics: 50.0, sensors: 20.0, control: 20.0, wifi: 10.0, network: 1.0 }
    }
}

/// The wifi module's rate \[Hz\] as built ([`crate::sim::SimBuilder::build`] inserts it; rates are
/// fixed from then on), for controllers whose defaults count wifi rounds.
#[derive(Resource, Debug, Clone, Copy, PartialEq)]
pub struct WifiRate(pub f64);

/// The simulation clock, set by the scheduler before it runs a module.
#[derive(Resource, Debug, Clone, Copy, Default, PartialEq)]
pub struct SimClock {
    /// Current sim time: the instant the running module is due at.
    pub now: SimTime,
    /// Step of the running module \[s\]: the time until its next tick (what dynamics integrates over).
    pub dt: f64,
}

/// Number of times every module of [`Phase::Control`] has run (the in-box epoch); V2V in-boxes use it to know when the
/// controllers have seen the rounds they hold.
#[derive(Resource, Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ControlEpoch(pub u64);

/// One module: a schedule with a rate and a phase.
struct Module {
    name: String,
    label: InternedScheduleLabel,
    phase: Phase,
    rate: f64,
    tick: u64,
    /// For a control-phase module: whether it has run since the in-box epoch last advanced.
    ran_since_epoch: bool,
    /// Wall time spent running the schedule, counted only while timing is on.
    busy: std::time::Duration,
    schedule: Schedule,
}

impl Module {
    /// Due time of tick `k`: rounded from `k / rate` each time, so rates never drift.
    fn due_at(&self, k: u64) -> SimTime {
        SimTime((k as f64 * 1e6 / self.rate).round() as u64)
    }
}

/// Runs the modules' schedules in due order; knows nothing of wall-clock time.
pub struct Scheduler {
    modules: Vec<Module>,
    now: SimTime,
    /// Whether each schedule run is timed ([`Scheduler::set_timing`]).
    timing: bool,
}

impl Default for Scheduler {
    fn default() -> Self {
        Scheduler { modules: Vec::new(), now: SimTime::ZERO, timing: false }
    }
}

impl Scheduler {
    /// Add a module with an empty schedule whose [`SimSystems`] sets are chained
    /// (single-threaded executor: the multi-threaded one costs more than it gains on small
    /// machines). A label that already exists is an error and changes nothing.
    ///
    /// # Panics
    /// If `rate` is not a positive finite number of Hz (a programming error: scenarios validate
    /// their rates before they get here).
    pub fn add_module(
        &mut self,
        name: &str,
        label: impl ScheduleLabel,
        phase: Phase,
        rate: f64,
    ) -> Result<(), DuplicateModule> {
        assert!(rate.is_finite() && rate > 0.0, "module {name}: rate must be positive and finite, got {rate} Hz");
        let label = label.intern();
        if let Some(i) = self.index(label) {
            return Err(DuplicateModule { label: format!("{label:?}"), existing: self.modules[i].name.clone() });
        }
        let mut schedule = Schedule::new(label);
        schedule.set_executor(SingleThreadedExecutor::new());
        schedule.configure_sets(
            (SimSystems::Sense, SimSystems::Communicate, SimSystems::Control, SimSystems::Integrate).chain(),
        );
        self.modules.push(Module {
            name: name.to_string(),
            label,
            phase,
            rate,
            tick: 0,
            ran_since_epoch: false,
            busy: std::time::Duration::ZERO,
            schedule,
        });
        Ok(())
    }

    fn index(&self, label: InternedScheduleLabel) -> Option<usize> {
        self.modules.iter().position(|m| m.label == label)
    }

    /// The schedule of module `label`.
    pub fn schedule_mut(&mut self, label: impl ScheduleLabel) -> Option<&mut Schedule> {
        let i = self.index(label.intern())?;
        Some(&mut self.modules[i].schedule)
    }

    /// Change the rate of module `label` \[Hz\]; returns false if there is no such module.
    ///
    /// # Panics
    /// If `rate` is not positive and finite, or the module has already run.
    pub fn set_rate(&mut self, label: impl ScheduleLabel, rate: f64) -> bool {
        assert!(rate.is_finite() && rate > 0.0, "rate must be positive and finite, got {rate} Hz");
        let Some(i) = self.index(label.intern()) else { return false };
        assert!(self.modules[i].tick == 0, "module {}: rates are fixed once it has run", self.modules[i].name);
        self.modules[i].rate = rate;
        true
    }

    /// Rate of module `label` \[Hz\].
    pub fn rate(&self, label: impl ScheduleLabel) -> Option<f64> {
        self.index(label.intern()).map(|i| self.modules[i].rate)
    }

    /// How many times module `label` has run.
    pub fn ticks(&self, label: impl ScheduleLabel) -> Option<u64> {
        self.index(label.intern()).map(|i| self.modules[i].tick)
    }

    /// Time every schedule run with the wall clock (two `Instant::now` calls per module tick;
    /// off by default). See [`Scheduler::module_times`].
    pub fn set_timing(&mut self, on: bool) {
        self.timing = on;
    }

    /// Wall time each module's schedule has run while timing was on \[s\], in the order the
    /// modules were added: where a run's time went, module by module.
    pub fn module_times(&self) -> impl Iterator<Item = (&str, f64)> {
        self.modules.iter().map(|m| (m.name.as_str(), m.busy.as_secs_f64()))
    }

    /// Names of all modules, in the order they were added.
    pub fn module_names(&self) -> impl Iterator<Item = &str> {
        self.modules.iter().map(|m| m.name.as_str())
    }

    /// Current sim time: the due time of the module that ran last, or the end of the last
    /// `run_until`.
    pub fn now(&self) -> SimTime {
        self.now
    }

    /// The module due next: (index, due time, its name, its period \[s\]).
    pub fn peek(&self) -> Option<(usize, SimTime, &str, f64)> {
        let (i, due) = self
            .modules
            .iter()
            .enumerate()
            .map(|(i, m)| (i, m.due_at(m.tick)))
            .min_by_key(|&(i, due)| (due, self.modules[i].phase, i))?;
        let m = &self.modules[i];
        Some((i, due, m.name.as_str(), 1.0 / m.rate))
    }

    /// Run the module due next; returns its due time.
    pub fn run_next(&mut self, world: &mut World) -> Option<SimTime> {
        let (i, due, _, _) = self.peek()?;
        let m = &mut self.modules[i];
        let next = m.due_at(m.tick + 1);
        let clock = SimClock { now: due, dt: (next.0 - due.0) as f64 * 1e-6 };
        match world.get_resource_mut::<SimClock>() {
            Some(mut c) => *c = clock,
            None => world.insert_resource(clock),
        }
        if self.timing {
            let start = std::time::Instant::now();
            m.schedule.run(world);
            m.busy += start.elapsed();
        } else {
            m.schedule.run(world);
        }
        m.tick += 1;
        // bevy keeps a record of every component removed (despawned vehicles' too) until the
        // trackers are cleared, as a bevy App does once per frame: without this a run with
        // traffic leaving the world grows by ~360 B per vehicle that left (nothing here reads
        // the records).
        world.clear_trackers();
        // Every control-phase module (the built-in `Control` and any of a student's) reads the
        // in-boxes: once each of them has run since the last advance, all have seen what the
        // in-boxes hold and the next V2V round may start them afresh. A slower controller so
        // never misses a round; a faster one sees the same rounds again.
        if m.phase == Phase::Control {
            m.ran_since_epoch = true;
            let controls = || self.modules.iter().filter(|m| m.phase == Phase::Control);
            if controls().all(|m| m.ran_since_epoch) {
                for m in self.modules.iter_mut().filter(|m| m.phase == Phase::Control) {
                    m.ran_since_epoch = false;
                }
                world.get_resource_or_insert_with(ControlEpoch::default).0 += 1;
            }
        }
        self.now = due;
        Some(due)
    }

    /// Run every module due strictly before `end`, then set the clock to `end`.
    pub fn run_until(&mut self, world: &mut World, end: SimTime) {
        while let Some((_, due, _, _)) = self.peek() {
            if due >= end {
                break;
            }
            self.run_next(world);
        }
        self.now = self.now.max(end);
        world.get_resource_or_insert_with(SimClock::default).now = self.now;
    }
}
