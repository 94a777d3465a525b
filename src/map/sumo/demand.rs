//! SUMO demand (`.rou.xml`).
