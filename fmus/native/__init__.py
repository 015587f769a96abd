"""Native (plain C) FMUs: build (build_native), generated physics and resources (physics_codegen), C sources."""
