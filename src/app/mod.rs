//! Sim builder, Plugin trait, scenario config, headless and real-time runners.
