"""The settings of the sensor bank: the TOML file of noise, filter, counter and A/D choices, and its checks.

:class:`SensorSettings` holds one setting per field (TOML ``[section] key`` -> ``section_key``);
:func:`load_sensor_settings` reads ``flexarm/data/sensors_default.toml`` or another file. The bank that uses
them, and the reasons for the defaults, are in :mod:`flexarm.sensors`, which re-exports these names.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .parameters import DATA_DIR

DEFAULT_SENSOR_FILE = DATA_DIR / "sensors_default.toml"


class SensorSettingsError(ValueError):
    """A sensor setting is missing, of the wrong type or outside its allowed range."""


@dataclass(frozen=True)
class SensorSettings:
    """Settings of a :class:`SensorBank`; TOML ``[section] key`` maps to field ``section_key``.

    Attributes
    ----------
    noise_enabled : bool
        Add the uniform noise below (the paper's "with noise" case).
    noise_seed : int
        Seed of the bank's PCG64 generator, in [0, 2**63 − 1].
    encoder_noise_deg : float
        Encoder noise half-width a (uniform on [−a, a)), deg, ≥ 0. Paper: 0.1.
    encoder_quantization : bool
        Round the encoder angles to whole counts.
    encoder_counts_per_rev : int
        Counts per motor revolution, in [2, 2**24]. Chosen: 4096.
    tachometer_noise_deg_per_s : float
        Tachometer noise half-width, deg/s, ≥ 0. Paper: 1.0.
    tachometer_full_scale_deg_per_s : float
        A/D full scale ±FS of the tachometer channels, deg/s, > 0.
    strain_gauge_noise_deg : float
        Noise half-width on each gauge's segment angle, deg, ≥ 0. Paper: 0.05.
    strain_gauge_filter : bool
        Apply the gauges' low-pass filter.
    strain_gauge_cutoff_hz : float
        Its −3 dB frequency, Hz, in (0, Nyquist). Paper: 100.
    strain_gauge_filter_order : int
        Butterworth order, in [1, 8].
    strain_gauge_full_scale_curvature_per_m : tuple of float, shape (2,)
        A/D full scale of the link-1 and link-2 gauges as curvature, 1/m, > 0.
    accelerometer_noise_m_per_s2 : float
        Accelerometer noise half-width, m/s², ≥ 0.
    accelerometer_filter : bool
        Apply the accelerometers' low-pass filter.
    accelerometer_cutoff_hz : float
        Its −3 dB frequency, Hz, in (0, Nyquist). Paper: 10.
    accelerometer_filter_order : int
        Butterworth order, in [1, 8].
    accelerometer_full_scale_m_per_s2 : float
        A/D full scale of the accelerometer channels, m/s², > 0.
    adc_quantization : bool
        Quantise the analogue channels (tachometers, gauges, accelerometers).
    adc_bits : int
        A/D resolution, in [2, 24]. Paper: 12.
    """

    noise_enabled: bool = True
    noise_seed: int = 1
    encoder_noise_deg: float = 0.1
    encoder_quantization: bool = False
    encoder_counts_per_rev: int = 4096
    tachometer_noise_deg_per_s: float = 1.0
    tachometer_full_scale_deg_per_s: float = 720.0
    strain_gauge_noise_deg: float = 0.05
    strain_gauge_filter: bool = False
    strain_gauge_cutoff_hz: float = 100.0
    strain_gauge_filter_order: int = 2
    strain_gauge_full_scale_curvature_per_m: tuple[float, float] = (0.5, 5.0)
    accelerometer_noise_m_per_s2: float = 0.0
    accelerometer_filter: bool = False
    accelerometer_cutoff_hz: float = 10.0
    accelerometer_filter_order: int = 2
    accelerometer_full_scale_m_per_s2: float = 98.0665
    adc_quantization: bool = False
    adc_bits: int = 12

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.type == "bool":
                if not isinstance(value, (bool, np.bool_)):
                    raise SensorSettingsError(f"{f.name}: must be true or false, got {value!r}")
                object.__setattr__(self, f.name, bool(value))
            elif f.type == "int":
                lo, hi = _INT_RANGES[f.name]
                if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
                    raise SensorSettingsError(f"{f.name}: must be an integer in [{lo}, {hi}], got {value!r}")
                if not lo <= value <= hi:
                    raise SensorSettingsError(f"{f.name}: {value} is outside the allowed range [{lo}, {hi}]")
                object.__setattr__(self, f.name, int(value))
            elif f.type == "float":
                object.__setattr__(self, f.name, _check_float(f.name, value, strict=not f.name.endswith(
                    _NOISE_SUFFIXES)))
            else:  # the per-link curvature full scales
                if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
                    raise SensorSettingsError(f"{f.name}: must be two numbers (link 1, link 2) > 0, got {value!r}")
                object.__setattr__(self, f.name, tuple(_check_float(f"{f.name}[{i}]", v, strict=True)
                                                       for i, v in enumerate(value)))

    def check_sample_time(self, dt: float) -> None:
        """Raise :class:`SensorSettingsError` unless both cut-offs lie in (0, 1/(2 dt)) Hz.

        Parameters
        ----------
        dt : float
            Sample time, s, finite and > 0.
        """
        if isinstance(dt, bool) or not isinstance(dt, (int, float, np.floating)) or not math.isfinite(dt) \
                or dt <= 0:
            raise SensorSettingsError(f"dt: must be a finite sample time > 0 s, got {dt!r}")
        nyquist = 0.5 / dt
        for name in ("strain_gauge_cutoff_hz", "accelerometer_cutoff_hz"):
            fc = getattr(self, name)
            if not fc < nyquist:
                raise SensorSettingsError(f"{name}: {fc} Hz is outside the allowed range (0, {nyquist:g}) Hz "
                                          f"(the Nyquist frequency at dt = {dt:g} s)")

    def replace(self, **changes) -> SensorSettings:
        """A validated copy with some fields changed."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise SensorSettingsError(f"unknown setting(s): {', '.join(sorted(unknown))}")
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        """Flat ``{field: value}`` dict (the names an FMU wrapper can expose as parameters)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, doc: Mapping) -> SensorSettings:
        """Build from a nested TOML-like dict (``{"encoder": {"noise_deg": 0.1}, ...}``).

        Top-level keys are field names; ``[section] key`` becomes ``section_key``.
        Missing keys keep their defaults; unknown keys are errors.
        """
        fields = {f.name for f in dataclasses.fields(cls)}
        flat = {}
        for key, value in doc.items():
            items = value.items() if isinstance(value, Mapping) else [(None, value)]
            for sub, v in items:
                name = key if sub is None else f"{key}_{sub}"
                if name not in fields:
                    where = key if sub is None else f"[{key}] {sub}"
                    raise SensorSettingsError(f"{where}: unknown sensor setting")
                flat[name] = v
        return cls(**flat)

    @classmethod
    def from_toml(cls, path: str | os.PathLike | None = None) -> SensorSettings:
        """Load a settings file (default: ``flexarm/data/sensors_default.toml``)."""
        path = Path(path) if path is not None else DEFAULT_SENSOR_FILE
        try:
            doc = tomllib.loads(path.read_bytes().decode())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError) as exc:
            raise SensorSettingsError(f"{path}: not valid TOML: {exc}") from exc
        try:
            return cls.from_dict(doc)
        except SensorSettingsError as exc:
            raise SensorSettingsError(f"{path}: {exc}") from exc


_INT_RANGES = {
    "noise_seed": (0, 2**63 - 1),
    "encoder_counts_per_rev": (2, 2**24),
    "strain_gauge_filter_order": (1, 8),
    "accelerometer_filter_order": (1, 8),
    "adc_bits": (2, 24),
}
_NOISE_SUFFIXES = ("_noise_deg", "_noise_deg_per_s", "_noise_m_per_s2")


def _check_float(name: str, value, strict: bool) -> float:
    """Finite number ≥ 0 (noise amplitudes) or > 0 (everything else)."""
    rng = "(0, inf)" if strict else "[0, inf)"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value):
        raise SensorSettingsError(f"{name}: must be a finite number in {rng}, got {value!r}")
    if value < 0 or (strict and value == 0):
        raise SensorSettingsError(f"{name}: {value} is outside the allowed range {rng}")
    return float(value)


def load_sensor_settings(path: str | os.PathLike | None = None, **overrides) -> SensorSettings:
    """Load sensor settings from TOML (default file) and apply flat field overrides."""
    settings = SensorSettings.from_toml(path)
    return settings.replace(**overrides) if overrides else settings
