//! Bridges to the lab: UDP visualisation stream, motion capture input, real-truck output.
