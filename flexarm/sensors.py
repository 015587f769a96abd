"""Sensor models of the Sandia arm (paper section 6) as a plain stepping library.

The bank reads the plant's true signals once per sample (1 ms) and returns
what the controller's VMEbus computer would see:

=========  ===========================  ============================================
channel    true signal                  measurement chain
=========  ===========================  ============================================
encoders   q1 = θ1, q2 = θ7 − θ6        + noise → counter quantisation
tachos     q̇1, q̇2                      + noise → 12-bit A/D
gauges     ε_1,1 … ε_2,3 (eqs. 23-31)   low-pass → + noise → 12-bit A/D
accels     tip acceleration ⟂ link      low-pass → + noise → 12-bit A/D
=========  ===========================  ============================================

Every stage is switchable (:class:`SensorSettings`, in :mod:`flexarm.sensor_settings`); with
filters, noise and quantisation off the bank returns the true signals exactly.

Choices (the paper is silent; defaults in ``flexarm/data/sensors_default.toml``):

* **Filters.** The hardware has analogue 100 Hz (gauges) and 10 Hz
  (accelerometers) low-pass filters of unstated type. We use Butterworth
  filters (default order 2) discretised by the bilinear transform with
  frequency pre-warping at the sample rate (:func:`scipy.signal.butter` with
  ``fs``, computed by :mod:`flexarm.filter_design`), so the gain is exactly −3.01 dB at the cut-off and 1 at DC. The
  state is set to steady state on the first sample after :meth:`SensorBank.reset`,
  so a constant input gives no start-up transient. Off by default: the
  paper's simulations had none.
* **Noise** is added after the filter, i.e. it is the error of the sampled
  value, as in the paper's simulations (zero-mean uniform: encoders ±0.1°,
  tachometers ±1.0 °/s, strain-gauge angles ±0.05°; accelerometers ±0 by
  default). Each sample draws exactly :data:`N_SIGNALS` uniforms from the
  bank's own ``numpy.random.Generator(PCG64(seed))`` in
  :data:`MEASURED_SIGNALS` order, whatever the amplitudes, so every channel's
  stream is reproducible bit for bit and depends only on the seed and the
  sample index.
* **Encoder counters** ("twelve bit encoder counters"): 4096 counts/rev
  (LSB 0.0879°) is our choice. The counter is read as an unwrapped,
  multi-turn angle rounded to the nearest count.
* **A/D** ("twelve bit A/D channels"): bipolar, round to nearest, codes
  −2^(b−1) … 2^(b−1)−1 with LSB = 2·FS/2^b, saturating. The full scales
  (tachometer ±720 °/s, gauges ±0.5 and ±5 m⁻¹ curvature on links 1 and 2,
  accelerometers ±10 g) are our choices. The gauges are digitised as
  curvature, so their angle LSB is the curvature LSB times the segment length.

Strain gauges: the paper converts gauge counts to curvature (rad/m) and
multiplies by the element length (one third of the flexible link) to get the
angle in rad: angle = curvature × segment length (:func:`curvature_to_angle`,
:func:`angle_to_curvature`). The bank's outputs are angles; the curvature is
available through :meth:`SensorBank.curvatures`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

from . import sensor_law as law
from .filter_design import butterworth_lowpass
from .model import ArmModel, joint_angles, joint_velocities, strain_gauge_angles
from .parameters import N_ELEMENTS, STRAIN_GAUGE_ELEMENTS, ArmParameters
from .sensor_settings import DEFAULT_SENSOR_FILE as DEFAULT_SENSOR_FILE  # re-exported: the settings' own module
from .sensor_settings import SensorSettings as SensorSettings
from .sensor_settings import SensorSettingsError as SensorSettingsError
from .sensor_settings import load_sensor_settings as load_sensor_settings
from .signals import signals as catalogue_signals


class SignalInfo(NamedTuple):
    """Name, unit and meaning of one signal of the sensor vectors."""

    name: str
    unit: str
    description: str


#: The plant's true signals, the bank's input vector, in order (the sensors FMU's inputs in the signal catalogue).
TRUE_SIGNALS: tuple[SignalInfo, ...] = tuple(SignalInfo(s.name, s.unit, s.description)
                                             for s in catalogue_signals("sensors", "input", indices=False))
#: The bank's measured output vector, in order (same channels as TRUE_SIGNALS; the sensors FMU's outputs).
MEASURED_SIGNALS: tuple[SignalInfo, ...] = tuple(SignalInfo(s.name, s.unit, s.description)
                                                 for s in catalogue_signals("sensors", "output", indices=False))
TRUE_SIGNAL_NAMES: tuple[str, ...] = tuple(s.name for s in TRUE_SIGNALS)
MEASURED_SIGNAL_NAMES: tuple[str, ...] = tuple(s.name for s in MEASURED_SIGNALS)
N_SIGNALS = len(TRUE_SIGNALS)

#: Channel groups, as slices of both vectors.
ENCODERS = slice(0, 2)
TACHOMETERS = slice(2, 4)
STRAIN_GAUGES = slice(4, 10)
ACCELEROMETERS = slice(10, 12)


# -- conversions ------------------------------------------------------------------
def strain_gauge_segment_lengths(params: ArmParameters) -> np.ndarray:
    """Length of the segment carrying each strain gauge, m, shape (6,), order ε_1,1 … ε_2,3."""
    return np.asarray(params.length, dtype=float)[list(STRAIN_GAUGE_ELEMENTS)].copy()


def curvature_to_angle(curvature, segment_lengths) -> np.ndarray:
    """Gauge curvature (1/m) → segment angle (rad): angle = curvature × segment length (paper §6).

    Parameters
    ----------
    curvature : array_like, shape (..., 6)
        Mean curvature over each gauged segment, 1/m.
    segment_lengths : array_like, shape (6,)
        Segment lengths, m (:func:`strain_gauge_segment_lengths`).
    """
    return np.asarray(curvature, dtype=float) * np.asarray(segment_lengths, dtype=float)


def angle_to_curvature(angle, segment_lengths) -> np.ndarray:
    """Segment angle (rad) → mean curvature (1/m), the inverse of :func:`curvature_to_angle`.

    Parameters
    ----------
    angle : array_like, shape (..., 6)
        Segment angles relative to the proximal neighbour, rad.
    segment_lengths : array_like, shape (6,)
        Segment lengths, m.
    """
    return np.asarray(angle, dtype=float) / np.asarray(segment_lengths, dtype=float)


def quantize(x, lsb, lo_code: float = -np.inf, hi_code: float = np.inf) -> np.ndarray:
    """Round to the nearest multiple of `lsb`, with the code clipped to [lo_code, hi_code].

    Parameters
    ----------
    x : array_like
        Signal, any unit.
    lsb : float or array_like broadcasting with `x`
        Quantisation step, same unit as `x`, > 0.
    lo_code, hi_code : float
        Saturation codes (±inf: no saturation).

    Returns
    -------
    ndarray
        ``code × lsb`` (|error| ≤ lsb/2 inside the range).
    """
    return law.quantize(np.asarray(x, dtype=float), lsb, lo_code, hi_code)


def true_signals_from_state(model: ArmModel, z, tau) -> np.ndarray:
    """The true-signal vector (:data:`TRUE_SIGNALS` order) of a plant state.

    Parameters
    ----------
    model : ArmModel
    z : array_like, shape (22,)
        State (θ_1..θ_11 rad, θ̇_1..θ̇_11 rad/s).
    tau : array_like, shape (2,)
        Motor torques acting at this instant, N·m (the accelerometers read
        the acceleration they cause).

    Returns
    -------
    ndarray, shape (12,)
    """
    z = np.asarray(z, dtype=float)
    if z.shape != (2 * N_ELEMENTS,):
        raise ValueError(f"z: expected shape ({2 * N_ELEMENTS},), got {z.shape}")
    theta, omega = z[:N_ELEMENTS], z[N_ELEMENTS:]
    return np.concatenate([joint_angles(theta), joint_velocities(omega), strain_gauge_angles(theta),
                           model.accelerometer_signals(theta, omega, tau)])


def as_dict(values, names: tuple[str, ...] = MEASURED_SIGNAL_NAMES) -> dict[str, float]:
    """``{name: value}`` for a signal vector (default: a measured vector)."""
    values = np.asarray(values, dtype=float)
    if values.shape != (len(names),):
        raise ValueError(f"values: expected shape ({len(names)},), got {values.shape}")
    return dict(zip(names, values.tolist()))


# -- filters ----------------------------------------------------------------------
class _LowPassBank:
    """One Butterworth low-pass (as second-order sections) applied to several channels.

    Direct form II transposed, as :func:`scipy.signal.sosfilt`, stepped one
    sample at a time; state shape (n_sections, n_channels, 2).
    """

    def __init__(self, order: int, cutoff_hz: float, dt: float, n_channels: int):
        # Pre-warped before the bilinear transform, so the digital filter's −3 dB point is exactly cutoff_hz; with
        # each section's state for a unit step in steady state, scaled by the first sample to start without a
        # transient (flexarm.filter_design, the design the native FMU's C is generated from).
        self.sos, self.zi_unit = butterworth_lowpass(order, cutoff_hz, 1.0 / dt)
        self.state = np.zeros((self.sos.shape[0], n_channels, 2))

    def prime(self, x: np.ndarray) -> None:
        self.state = law.primed_state(self.zi_unit[:, None, :], x[None, :, None])

    def step(self, x: np.ndarray) -> np.ndarray:
        y = x
        for k, sos in enumerate(self.sos):
            s = self.state[k]
            y, s[:, 0], s[:, 1] = law.filter_section(sos, s[:, 0], s[:, 1], y)
        return y


# -- the bank -----------------------------------------------------------------------
class SensorBank:
    """Encoders, tachometers, strain gauges and accelerometers of the arm, stepped per sample.

    Parameters
    ----------
    settings : SensorSettings, optional
        Defaults to ``flexarm/data/sensors_default.toml``.
    params : ArmParameters, optional
        Arm parameters (for the gauges' segment lengths). Defaults to the
        committed Sandia arm.
    dt : float
        Sample time, s (the paper: 1 ms). The filter cut-offs must lie below
        the Nyquist frequency 1/(2 dt).

    Notes
    -----
    Call :meth:`measure` once per sample with the true-signal vector. The
    bank is a deterministic function of the settings, the seed and the input
    sequence; :meth:`get_state` / :meth:`set_state` snapshot and restore it
    (filter states and generator state), so a restored bank reproduces its
    outputs bit for bit.
    """

    def __init__(self, settings: SensorSettings | None = None, params: ArmParameters | None = None,
                 dt: float = 1e-3):
        if settings is None:
            settings = SensorSettings.from_toml()
        if params is None:
            from .parameters import load_parameters
            params = load_parameters()
        settings.check_sample_time(dt)
        self.settings = settings
        self.dt = float(dt)
        s = settings
        self.segment_lengths = strain_gauge_segment_lengths(params)

        amplitude, self.encoder_lsb, analogue_full_scale, analogue_lsb, lo_code, hi_code = law.channel_scales(
            s.encoder_noise_deg, s.tachometer_noise_deg_per_s, s.strain_gauge_noise_deg, s.accelerometer_noise_m_per_s2,
            s.encoder_counts_per_rev, s.tachometer_full_scale_deg_per_s, s.strain_gauge_full_scale_curvature_per_m,
            self.segment_lengths, s.accelerometer_full_scale_m_per_s2, 2.0 ** s.adc_bits)
        #: Noise half-widths per channel, SI units, shape (12,).
        self.noise_amplitude = amplitude
        #: Encoder LSB, rad (self.encoder_lsb, above).
        #: A/D full scale ±FS per channel (inf for the encoders), SI units, shape (12,); gauges are digitised as
        #: curvature, so in angle the full scale scales with the segment length.
        self.full_scale = np.concatenate([[np.inf, np.inf], analogue_full_scale])
        #: A/D LSB per analogue channel, SI units, shape (12,) (encoders: nan).
        self.adc_lsb = np.concatenate([[np.nan, np.nan], analogue_lsb])
        self._code_range = (lo_code, hi_code)

        self._strain_filter = (_LowPassBank(s.strain_gauge_filter_order, s.strain_gauge_cutoff_hz, dt, 6)
                               if s.strain_gauge_filter else None)
        self._acc_filter = (_LowPassBank(s.accelerometer_filter_order, s.accelerometer_cutoff_hz, dt, 2)
                            if s.accelerometer_filter else None)
        self.reset()

    # -- stepping ---------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """Restart: new generator from the seed, filters re-primed on the next sample.

        Parameters
        ----------
        seed : int, optional
            Overrides ``settings.noise_seed`` for this run (and later resets
            without a seed return to the settings' seed).
        """
        if seed is None:
            seed = self.settings.noise_seed
        else:
            self.settings.replace(noise_seed=seed)  # validates the seed
        self._rng = np.random.Generator(np.random.PCG64(int(seed)))
        self._primed = False
        self.n_samples = 0

    def measure(self, true_signals) -> np.ndarray:
        """One sample: the measured vector from the true one.

        Parameters
        ----------
        true_signals : array_like, shape (12,), or mapping
            In :data:`TRUE_SIGNALS` order and units, or ``{name: value}`` with
            every name of :data:`TRUE_SIGNAL_NAMES`.

        Returns
        -------
        ndarray, shape (12,)
            In :data:`MEASURED_SIGNALS` order and units.

        Notes
        -----
        Non-finite inputs are passed through (a diverging simulation is a
        result, not a sensor error); they do poison the filter state.
        """
        x = self._as_vector(true_signals)
        s = self.settings
        if not self._primed:
            for flt, sl in ((self._strain_filter, STRAIN_GAUGES), (self._acc_filter, ACCELEROMETERS)):
                if flt is not None:
                    flt.prime(x[sl])
            self._primed = True
        y = x.copy()
        if self._strain_filter is not None:
            y[STRAIN_GAUGES] = self._strain_filter.step(x[STRAIN_GAUGES])
        if self._acc_filter is not None:
            y[ACCELEROMETERS] = self._acc_filter.step(x[ACCELEROMETERS])
        # Always draw N_SIGNALS uniforms so each channel's noise depends on
        # the seed and the sample index only, never on the other settings.
        u = self._rng.random(N_SIGNALS)
        if s.noise_enabled:
            y = law.with_noise(y, self.noise_amplitude, u)
        if s.encoder_quantization:
            y[ENCODERS] = quantize(y[ENCODERS], self.encoder_lsb)
        if s.adc_quantization:
            lo, hi = self._code_range
            y[2:] = quantize(y[2:], self.adc_lsb[2:], lo, hi)
        self.n_samples += 1
        return y

    def skip(self) -> np.ndarray:
        """A sample with nothing to measure (a master's placeholder before its first exchange).

        Nothing is drawn and nothing counted: the noise of the n-th real measurement is the n-th draw, so the
        plant's sample j gets the same noise in a master that sends placeholders first (fmpy's ``simulate_ssp``)
        as in one that exchanged values in initialisation. The filters keep their state (unprimed until the
        first real sample primes them). Returns zeros, shape (12,): the placeholder passed on, never a
        measurement.
        """
        return np.zeros(N_SIGNALS)

    def measure_state(self, model: ArmModel, z, tau) -> np.ndarray:
        """:meth:`measure` of :func:`true_signals_from_state` ``(model, z, tau)``; shape (12,)."""
        return self.measure(true_signals_from_state(model, z, tau))

    def curvatures(self, measured) -> np.ndarray:
        """The gauges' curvatures, 1/m, shape (6,), from a measured vector (shape (12,))."""
        return angle_to_curvature(np.asarray(measured, dtype=float)[STRAIN_GAUGES], self.segment_lengths)

    # -- state ------------------------------------------------------------------
    def get_state(self) -> dict:
        """A deep, picklable snapshot: generator state, filter states, priming flag, sample count."""
        return {
            "rng": _copy_rng_state(self._rng.bit_generator.state),
            "primed": self._primed,
            "n_samples": self.n_samples,
            "strain_filter": None if self._strain_filter is None else self._strain_filter.state.copy(),
            "acc_filter": None if self._acc_filter is None else self._acc_filter.state.copy(),
        }

    def checkpoint(self) -> dict:
        """A light snapshot for :meth:`rewind`: filter states, priming flag, sample count.

        Unlike :meth:`get_state` it does not copy the generator (which is rewound
        instead), so it costs next to nothing; the sensors FMU takes one per sample.
        """
        return {
            "primed": self._primed,
            "n_samples": self.n_samples,
            "strain_filter": None if self._strain_filter is None else self._strain_filter.state.copy(),
            "acc_filter": None if self._acc_filter is None else self._acc_filter.state.copy(),
        }

    def rewind(self, checkpoint: Mapping) -> None:
        """Return to a :meth:`checkpoint` of this bank: the next :meth:`measure` repeats the samples since.

        The generator is stepped back by the uniforms drawn since (every sample
        draws exactly :data:`N_SIGNALS`), so the noise repeats bit for bit.
        """
        back = self.n_samples - int(checkpoint["n_samples"])
        if back < 0:
            raise ValueError(f"checkpoint: taken at sample {checkpoint['n_samples']}, after this bank's "
                             f"{self.n_samples} samples (not a checkpoint of this bank's past)")
        for key, flt in (("strain_filter", self._strain_filter), ("acc_filter", self._acc_filter)):
            saved = checkpoint[key]
            if (saved is None) != (flt is None) or (flt is not None and np.shape(saved) != flt.state.shape):
                raise ValueError(f"checkpoint[{key!r}]: does not match this bank's filter settings")
            if flt is not None:
                flt.state = np.array(saved, dtype=float)
        if back:
            self._rng.bit_generator.advance(-N_SIGNALS * back)
        self._primed = bool(checkpoint["primed"])
        self.n_samples = int(checkpoint["n_samples"])

    def set_state(self, state: Mapping) -> None:
        """Restore a snapshot of :meth:`get_state` (of a bank with the same settings)."""
        for key, flt in (("strain_filter", self._strain_filter), ("acc_filter", self._acc_filter)):
            saved = state[key]
            if (saved is None) != (flt is None) or (flt is not None and np.shape(saved) != flt.state.shape):
                raise ValueError(f"state[{key!r}]: does not match this bank's filter settings")
        rng = np.random.Generator(np.random.PCG64())
        rng.bit_generator.state = _copy_rng_state(state["rng"])
        self._rng = rng
        if self._strain_filter is not None:
            self._strain_filter.state = np.array(state["strain_filter"], dtype=float)
        if self._acc_filter is not None:
            self._acc_filter.state = np.array(state["acc_filter"], dtype=float)
        self._primed = bool(state["primed"])
        self.n_samples = int(state["n_samples"])

    # -- helpers ----------------------------------------------------------------
    @staticmethod
    def _as_vector(true_signals) -> np.ndarray:
        if isinstance(true_signals, Mapping):
            missing = [n for n in TRUE_SIGNAL_NAMES if n not in true_signals]
            if missing:
                raise ValueError(f"true_signals: missing {', '.join(missing)}")
            return np.array([true_signals[n] for n in TRUE_SIGNAL_NAMES], dtype=float)
        x = np.array(true_signals, dtype=float)
        if x.shape != (N_SIGNALS,):
            raise ValueError(f"true_signals: expected shape ({N_SIGNALS},) in TRUE_SIGNALS order, got {x.shape}")
        return x


def _copy_rng_state(state: Mapping) -> dict:
    """Copy of a bit generator's state dict: nested dicts copied, ints shared (immutable).

    Cheaper than ``copy.deepcopy``; the sensors FMU snapshots it at every step.
    """
    return {k: _copy_rng_state(v) if isinstance(v, Mapping) else v for k, v in state.items()}
