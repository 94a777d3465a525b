//! Controllers (path following, cruise control, ACC, platooning) as plugins.
