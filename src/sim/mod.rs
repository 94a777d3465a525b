//! Scheduled systems: clock, multi-rate scheduler, dynamics models, sensors and V2V.
