//! Off-screen wgpu bird's-eye renderer: reads the world and the map, never writes them.
