//! ECS data: vehicle components, resources, the vehicle registry and spawning.
