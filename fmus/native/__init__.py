"""Native (plain C) FMUs: C sources only (built by fmu_build.native_build, physics by fmu_build.native_codegen)."""
