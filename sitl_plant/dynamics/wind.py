"""Wind: the air's velocity in NED, as a function of time (and place).

Every wind is an object with ``velocity_ned(time_s, pos_ned_m) -> ndarray (3,)`` (m/s, the
velocity of the air, NED), which ``VehicleSim`` samples once per physics step and the rigid
body feels through its linear drag. Kinds:

- ``ConstantWind``: a steady velocity.
- ``GustWind``: discrete "1-cosine" gusts (MIL-F-8785C's discrete gust shape, rising and
  falling back as the CS-25.341 gust does).
- ``DrydenTurbulence``: a mean wind plus continuous Dryden turbulence (MIL-F-8785C low altitude
  model), white noise through the Dryden shaping filters, discretised exactly; seeded.
- ``CompositeWind``: the sum of several.

Directions are headings the air moves **towards**, degrees clockwise from north (so
``dir=90`` blows towards the east; a meteorologist's "wind from" is this plus 180).

Each kind also has ``velocity_ned_many(times_s) -> ndarray (n, 3)``: ``velocity_ned`` at many
times at once, the same numbers (every wind here depends on time only), for the batched sweep.

Two ways in: a command-line spec (``wind_from_spec("constant:3,0,0+dryden:5", seed)``) and a
TOML table (``wind_from_table``). See ``docs/model.md`` for the equations and sources.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from offboard.model.errors import UserError
from offboard.model.tomlfile import Fields
from sitl_plant.dynamics import specstring

__all__ = [
    "WindField",
    "WindSpecError",
    "ConstantWind",
    "Gust",
    "GustWind",
    "DrydenTurbulence",
    "CompositeWind",
    "DrydenParameters",
    "dryden_parameters",
    "wind_from_spec",
    "wind_from_table",
    "WIND_SPEC_HELP",
]

FT = 0.3048  # metres per foot

WIND_SPEC_HELP = (
    "none | constant:N,E,D | dryden:SPEED[,dir=DEG,alt=M,airspeed=M_S] | "
    "gust:t=S,amp=M_S,dur=S[,dir=DEG], joined with '+' (speeds m/s; dir = heading the air moves towards)"
)


class WindField(Protocol):
    """Anything that gives the air's velocity."""

    def velocity_ned(self, time_s: float, pos_ned_m: np.ndarray) -> np.ndarray:
        """Air velocity (m/s, NED) at ``time_s`` and ``pos_ned_m``."""
        ...


class WindSpecError(UserError, ValueError):
    """A wind spec string or table the user wrote is malformed; the message is one line."""


def _horizontal(speed_m_s: float, direction_deg: float) -> np.ndarray:
    heading = math.radians(direction_deg)
    return np.array([speed_m_s * math.cos(heading), speed_m_s * math.sin(heading), 0.0])


@dataclass(frozen=True)
class ConstantWind:
    """A steady wind.

    Parameters
    ----------
    velocity_ned_m_s : array_like, shape (3,)
        The air's velocity, NED, m/s.
    """

    velocity_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        v = tuple(float(c) for c in self.velocity_ned_m_s)
        if len(v) != 3 or not all(math.isfinite(c) for c in v):
            raise ValueError(f"velocity_ned_m_s must be 3 finite numbers, got {self.velocity_ned_m_s}")
        object.__setattr__(self, "velocity_ned_m_s", v)

    def velocity_ned(self, time_s: float, pos_ned_m: np.ndarray) -> np.ndarray:
        """The constant velocity, NED, m/s."""
        return np.array(self.velocity_ned_m_s)

    def velocity_ned_many(self, times_s: np.ndarray) -> np.ndarray:
        """The constant velocity at each of ``times_s``: (n, 3)."""
        return np.tile(np.array(self.velocity_ned_m_s), (len(times_s), 1))


@dataclass(frozen=True)
class Gust:
    """One discrete gust: ``v(t) = A/2 (1 - cos(2 pi (t - t0) / d))`` for ``t0 <= t <= t0 + d``.

    The 1-cosine shape of MIL-F-8785C (section 3.7.5), rising over ``d/2`` to the amplitude
    and falling back over the other half (the full 1-cosine of CS-25.341); zero outside.

    Attributes
    ----------
    start_s : float
        t0, when the gust begins.
    amplitude_m_s : float
        A, the peak air speed added, reached at ``t0 + d/2``.
    duration_s : float
        d, > 0.
    direction_deg : float
        Heading the gust blows towards, degrees clockwise from north.
    """

    start_s: float
    amplitude_m_s: float
    duration_s: float
    direction_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("start_s", "amplitude_m_s", "duration_s", "direction_deg"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"gust {name} must be finite")
        if not self.duration_s > 0:
            raise ValueError(f"gust duration_s must be > 0, got {self.duration_s}")

    def speed(self, time_s: float) -> float:
        """The gust's speed (m/s) at ``time_s``."""
        phase = (time_s - self.start_s) / self.duration_s
        if not 0.0 <= phase <= 1.0:
            return 0.0
        return 0.5 * self.amplitude_m_s * (1.0 - math.cos(2.0 * math.pi * phase))

    def speeds(self, times_s: np.ndarray) -> np.ndarray:
        """``speed`` at each of ``times_s`` (the cosine by ``math.cos``, as ``speed`` takes it)."""
        out = np.zeros(len(times_s))
        for k in np.nonzero((times_s >= self.start_s) & (times_s <= self.start_s + self.duration_s))[0]:
            out[k] = self.speed(float(times_s[k]))
        return out


@dataclass(frozen=True)
class GustWind:
    """The sum of discrete 1-cosine gusts (``Gust``), each horizontal along its direction."""

    gusts: tuple[Gust, ...]

    def velocity_ned(self, time_s: float, pos_ned_m: np.ndarray) -> np.ndarray:
        """The gusts' sum at ``time_s`` (horizontal; the same everywhere), NED, m/s."""
        total = np.zeros(3)
        for gust in self.gusts:
            speed = gust.speed(time_s)
            if speed:
                total += _horizontal(speed, gust.direction_deg)
        return total

    def velocity_ned_many(self, times_s: np.ndarray) -> np.ndarray:
        """``velocity_ned`` at each of ``times_s``: (n, 3)."""
        total = np.zeros((len(times_s), 3))
        for gust in self.gusts:
            speed = gust.speeds(times_s)
            heading = math.radians(gust.direction_deg)
            total[:, 0] += speed * math.cos(heading)  # _horizontal's products, element by element
            total[:, 1] += speed * math.sin(heading)
        return total


@dataclass(frozen=True)
class DrydenParameters:
    """Length scales (m) and intensities (m/s) of the low-altitude Dryden model."""

    length_u_m: float
    length_v_m: float
    length_w_m: float
    sigma_u_m_s: float
    sigma_v_m_s: float
    sigma_w_m_s: float


def dryden_parameters(mean_speed_6m_m_s: float, altitude_m: float) -> DrydenParameters:
    """MIL-F-8785C low-altitude turbulence scales and intensities (section 3.7.3, fig. 10-11).

    With ``h`` the altitude in feet, clamped to the model's range [10, 1000] ft, and ``W20``
    the wind speed at 20 ft (6 m)::

        L_w = h,   L_u = L_v = h / (0.177 + 0.000823 h)**1.2
        sigma_w = 0.1 W20,   sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)**0.4

    Parameters
    ----------
    mean_speed_6m_m_s : float
        W20, m/s (light turbulence ~ 7.7 m/s, moderate ~ 15, severe ~ 23 in MIL-F-8785C).
    altitude_m : float
        Height above ground, m.
    """
    h_ft = min(max(altitude_m / FT, 10.0), 1000.0)
    factor = 0.177 + 0.000823 * h_ft
    length_uv = h_ft / factor**1.2 * FT
    sigma_w = 0.1 * mean_speed_6m_m_s
    sigma_uv = sigma_w / factor**0.4
    return DrydenParameters(length_uv, length_uv, h_ft * FT, sigma_uv, sigma_uv, sigma_w)


def _first_order(time_constant_s: float, step_s: float) -> tuple[np.ndarray, ...]:
    """Exact step of ``T x' = -x + n`` at unit variance (an Ornstein-Uhlenbeck process).

    Returns (Ad, noise gain, stationary gain, output row) as 1x1 / 1-vector arrays.
    """
    a = math.exp(-step_s / time_constant_s)
    return np.array([[a]]), np.array([[math.sqrt(1.0 - a * a)]]), np.eye(1), np.ones(1)


def _second_order(time_constant_s: float, step_s: float) -> tuple[np.ndarray, ...]:
    """Exact step of the Dryden v/w filter ``(1 + sqrt(3) T s) / (1 + T s)**2``.

    Realised as two lags, ``T x1' = -x1 + n``, ``T x2' = -x2 + x1``, with output
    ``sqrt(3) x1 + (1 - sqrt(3)) x2`` scaled to unit variance. Over a step h,
    ``x(k+1) = Ad x(k) + e``, ``Ad = exp(-h/T) [[1, 0], [h/T, 1]]``, and the noise covariance
    is ``Qd = P - Ad P Ad^T`` with P the stationary covariance (Lyapunov equation).
    """
    t = time_constant_s
    a = np.array([[-1.0, 0.0], [1.0, -1.0]]) / t
    bbt = np.array([[1.0 / (t * t), 0.0], [0.0, 0.0]])
    eye = np.eye(2)  # A P + P A^T = -B B^T, as a 4x4 linear system on vec(P)
    p = np.linalg.solve(np.kron(eye, a) + np.kron(a, eye), -bbt.reshape(-1)).reshape(2, 2)
    p = 0.5 * (p + p.T)
    ad = math.exp(-step_s / t) * np.array([[1.0, 0.0], [step_s / t, 1.0]])
    qd = p - ad @ p @ ad.T
    c = np.array([math.sqrt(3.0), 1.0 - math.sqrt(3.0)])
    return ad, np.linalg.cholesky(0.5 * (qd + qd.T)), np.linalg.cholesky(p), c / math.sqrt(float(c @ p @ c))


def _block_diagonal(blocks: list[np.ndarray]) -> np.ndarray:
    size = sum(b.shape[0] for b in blocks)
    out = np.zeros((size, size))
    i = 0
    for b in blocks:
        out[i : i + b.shape[0], i : i + b.shape[0]] = b
        i += b.shape[0]
    return out


class DrydenTurbulence:
    """A mean wind plus Dryden turbulence (MIL-F-8785C, low altitude), seeded.

    The turbulence components, in the mean wind's axes (u along it, v to its right, w down),
    are white noise through the MIL-F-8785C shaping filters (Taylor's frozen turbulence at
    airspeed V, time constants ``T = L / V``)::

        H_u(s) ~ 1 / (1 + T_u s)                       autocorrelation sigma_u^2 exp(-tau/T_u)
        H_v(s) ~ (1 + sqrt(3) T_v s) / (1 + T_v s)^2   autocorrelation sigma_v^2 (1 - tau/2T_v) exp(-tau/T_v)

    and w as v; gains are set so each component's variance is exactly sigma^2 (the spectra
    of MIL-F-8785C section 3.7.3.2 with Omega = omega / V).
    The filters are stepped exactly (no discretisation error) on a fixed grid of
    ``sample_dt_s`` and linearly interpolated in between, so the wind is a deterministic
    function of time for a given seed, whatever rate it is sampled at; asking for an earlier
    time than the last grid point replays from the seed.

    Parameters
    ----------
    mean_speed_m_s : float
        W20, the wind speed at 6 m (20 ft), >= 0: the mean wind added, and what sets the
        intensities (``dryden_parameters``).
    direction_deg : float
        Heading the mean wind blows towards, degrees clockwise from north.
    altitude_m : float
        Height the scales and intensities are taken at (the model's range is 3-300 m).
    airspeed_m_s : float, optional
        V for the time constants; default the mean wind speed (a vehicle hovering in it).
    seed : int or sequence of int
        Seeds ``numpy.random.SeedSequence``.
    sample_dt_s : float
        The filters' step (default 0.01 s; the spectra have no power to speak of above it).
    """

    def __init__(
        self,
        mean_speed_m_s: float,
        direction_deg: float = 0.0,
        altitude_m: float = 10.0,
        airspeed_m_s: float | None = None,
        *,
        seed: int | Sequence[int] = 0,
        sample_dt_s: float = 0.01,
    ) -> None:
        if not (math.isfinite(mean_speed_m_s) and mean_speed_m_s >= 0):
            raise ValueError(f"mean_speed_m_s must be >= 0, got {mean_speed_m_s}")
        if not (math.isfinite(altitude_m) and altitude_m > 0):
            raise ValueError(f"altitude_m must be > 0, got {altitude_m}")
        if not math.isfinite(direction_deg):
            raise ValueError(f"direction_deg must be finite, got {direction_deg}")
        if not sample_dt_s > 0:
            raise ValueError(f"sample_dt_s must be > 0, got {sample_dt_s}")
        airspeed = mean_speed_m_s if airspeed_m_s is None else airspeed_m_s
        if not (math.isfinite(airspeed) and (airspeed > 0 or mean_speed_m_s == 0)):
            raise ValueError(f"airspeed_m_s must be > 0, got {airspeed}")
        self.mean_speed_m_s = float(mean_speed_m_s)
        self.direction_deg = float(direction_deg)
        self.altitude_m = float(altitude_m)
        self.airspeed_m_s = float(airspeed)
        self.sample_dt_s = float(sample_dt_s)
        self.seed = seed
        self.parameters = dryden_parameters(mean_speed_m_s, altitude_m)
        heading = math.radians(direction_deg)
        # columns: u (along the mean wind), v (to its right), w (down), in NED
        self._axes = np.array(
            [[math.cos(heading), -math.sin(heading), 0.0], [math.sin(heading), math.cos(heading), 0.0], [0.0, 0.0, 1.0]]
        )
        self._mean = _horizontal(mean_speed_m_s, direction_deg)
        par = self.parameters
        self._active = self.mean_speed_m_s > 0
        if self._active:
            filters = [
                _first_order(par.length_u_m / airspeed, sample_dt_s),
                _second_order(par.length_v_m / airspeed, sample_dt_s),
                _second_order(par.length_w_m / airspeed, sample_dt_s),
            ]
            # one 5-state linear system: x(k+1) = Ad x(k) + G n(k), turbulence_ned = M x
            self._ad = _block_diagonal([f[0] for f in filters])
            self._gain = _block_diagonal([f[1] for f in filters])
            self._stationary = _block_diagonal([f[2] for f in filters])
            sigmas = (par.sigma_u_m_s, par.sigma_v_m_s, par.sigma_w_m_s)
            local = np.zeros((3, 5))
            local[0, 0:1] = sigmas[0] * filters[0][3]
            local[1, 1:3] = sigmas[1] * filters[1][3]
            local[2, 3:5] = sigmas[2] * filters[2][3]
            self._output = self._axes @ local
        self._restart()

    @property
    def time_constants_s(self) -> tuple[float, float, float]:
        """``L / V`` for u, v, w."""
        par = self.parameters
        return tuple(length / self.airspeed_m_s for length in (par.length_u_m, par.length_v_m, par.length_w_m))  # type: ignore[return-value]

    def _restart(self) -> None:
        self._rng = np.random.default_rng(np.random.SeedSequence(self.seed))
        self._noise = np.empty((0, 5))
        self._used = 0
        self._index = 0
        if not self._active:
            return
        self._state = self._stationary @ self._draw()  # start in the stationary distribution
        self._now = self._output @ self._state
        self._next = self._advance()
        self._delta = self._next - self._now

    def _draw(self) -> np.ndarray:
        if self._used == len(self._noise):
            self._noise = self._rng.standard_normal((4096, 5))
            self._used = 0
        self._used += 1
        return self._noise[self._used - 1]

    def _advance(self) -> np.ndarray:
        self._state = self._ad @ self._state + self._gain @ self._draw()
        return self._output @ self._state

    def turbulence_ned(self, time_s: float) -> np.ndarray:
        """The turbulent part alone (m/s, NED) at ``time_s`` >= 0."""
        if not self._active:
            return np.zeros(3)
        position = max(time_s, 0.0) / self.sample_dt_s
        index = int(position)
        if index < self._index:
            self._restart()
        while self._index < index:
            self._now = self._next
            self._next = self._advance()
            self._delta = self._next - self._now
            self._index += 1
        return self._now + (position - index) * self._delta

    def velocity_ned(self, time_s: float, pos_ned_m: np.ndarray) -> np.ndarray:
        """The mean wind plus the turbulence at ``time_s`` (``turbulence_ned``; the same everywhere), NED, m/s."""
        return self._mean + self.turbulence_ned(time_s)

    def velocity_ned_many(self, times_s: np.ndarray) -> np.ndarray:
        """``velocity_ned`` at each of ``times_s`` (ascending): the grid stepped once to the last
        of them, each time interpolated as ``turbulence_ned`` does."""
        times_s = np.asarray(times_s, dtype=float)
        if not self._active or len(times_s) == 0:
            return self._mean + np.zeros((len(times_s), 3))
        position = np.maximum(times_s, 0.0) / self.sample_dt_s
        index = position.astype(np.int64)
        if int(index[0]) < self._index:
            self._restart()
        first = int(index[0])
        self.turbulence_ned(float(times_s[0]))  # the grid at the first time
        nows, deltas = [self._now], [self._delta]
        while self._index < int(index[-1]):
            self._now = self._next
            self._next = self._advance()
            self._delta = self._next - self._now
            self._index += 1
            nows.append(self._now)
            deltas.append(self._delta)
        k = index - first
        return self._mean + (np.asarray(nows)[k] + (position - index)[:, None] * np.asarray(deltas)[k])


@dataclass(frozen=True)
class CompositeWind:
    """The sum of several winds."""

    parts: tuple[WindField, ...]

    def velocity_ned(self, time_s: float, pos_ned_m: np.ndarray) -> np.ndarray:
        """The sum of the parts' velocities, NED, m/s."""
        total = np.zeros(3)
        for part in self.parts:
            total += part.velocity_ned(time_s, pos_ned_m)
        return total

    def velocity_ned_many(self, times_s: np.ndarray) -> np.ndarray:
        """The sum of the parts' ``velocity_ned_many`` (each part must have one): (n, 3)."""
        total = np.zeros((len(times_s), 3))
        for part in self.parts:
            total += part.velocity_ned_many(times_s)  # type: ignore[attr-defined]
        return total


def _combine(parts: list[WindField]) -> WindField:
    gusts = [g for p in parts if isinstance(p, GustWind) for g in p.gusts]
    others = [p for p in parts if not isinstance(p, GustWind)]
    if gusts:
        others.append(GustWind(tuple(gusts)))
    if not others:
        return ConstantWind()
    return others[0] if len(others) == 1 else CompositeWind(tuple(others))


# --- the command-line spec ---------------------------------------------------------------------


def _fail(part: str) -> specstring.Fail:
    return lambda message: WindSpecError(f"wind spec {part!r}: {message}")


def _parse_part(part: str, seed: Sequence[int]) -> WindField:
    kind, args = specstring.kind_and_args(part)
    fail = _fail(part)
    if kind == "none":
        if args:
            raise WindSpecError(f"wind spec {part!r}: 'none' takes no arguments")
        return ConstantWind()
    if kind == "constant":
        values = [v.strip() for v in args.split(",")] if args else []
        if len(values) != 3:
            raise WindSpecError(f"wind spec {part!r}: expected constant:NORTH,EAST,DOWN (3 numbers in m/s)")
        return ConstantWind(tuple(specstring.number("velocity", v, fail) for v in values))  # type: ignore[arg-type]
    if kind == "dryden":
        speed_text, _, rest = args.partition(",")
        if not speed_text.strip():
            raise WindSpecError(f"wind spec {part!r}: expected dryden:SPEED[,dir=DEG,alt=M,airspeed=M_S]")
        speed = specstring.number("speed", speed_text.strip(), fail)
        if speed < 0:
            raise WindSpecError(f"wind spec {part!r}: speed must be >= 0, got {speed:g}")
        options = specstring.options(rest, ("dir", "alt", "airspeed"), fail) if rest.strip() else {}
        altitude = specstring.number("alt", options.get("alt", "10"), fail)
        if altitude <= 0:
            raise WindSpecError(f"wind spec {part!r}: alt must be > 0, got {altitude:g}")
        airspeed = specstring.number("airspeed", options["airspeed"], fail) if "airspeed" in options else None
        if airspeed is not None and airspeed <= 0:
            raise WindSpecError(f"wind spec {part!r}: airspeed must be > 0, got {airspeed:g}")
        return DrydenTurbulence(
            speed, specstring.number("dir", options.get("dir", "0"), fail), altitude, airspeed, seed=tuple(seed)
        )
    if kind == "gust":
        options = specstring.options(args, ("t", "amp", "dur", "dir"), fail) if args else {}
        missing = [key for key in ("t", "amp", "dur") if key not in options]
        if missing:
            raise WindSpecError(f"wind spec {part!r}: missing {', '.join(missing)} (gust:t=S,amp=M_S,dur=S[,dir=DEG])")
        duration = specstring.number("dur", options["dur"], fail)
        if duration <= 0:
            raise WindSpecError(f"wind spec {part!r}: dur must be > 0, got {duration:g}")
        gust = Gust(
            specstring.number("t", options["t"], fail),
            specstring.number("amp", options["amp"], fail),
            duration,
            specstring.number("dir", options.get("dir", "0"), fail),
        )
        return GustWind((gust,))
    raise WindSpecError(f"wind spec {part!r}: unknown kind {kind!r} (expected none, constant, dryden or gust)")


def wind_from_spec(spec: str, seed: int = 0) -> WindField:
    """A wind from a command-line spec such as ``"constant:3,0,0+dryden:5,dir=90"``.

    Grammar (``WIND_SPEC_HELP``): parts joined with ``+``, each one of ``none``,
    ``constant:N,E,D`` (m/s, NED), ``dryden:SPEED[,dir=DEG,alt=M,airspeed=M_S]`` (mean wind
    at 6 m plus its turbulence; defaults dir 0, alt 10 m, airspeed = SPEED) and
    ``gust:t=S,amp=M_S,dur=S[,dir=DEG]``. ``dir`` is the heading the air moves towards.

    Parameters
    ----------
    spec : str
        The spec.
    seed : int
        Base seed; the i-th part is seeded with ``(seed, i)``.

    Raises
    ------
    WindSpecError
        (a ``ValueError``) naming the bad part, in one line.
    """
    if not spec.strip():
        raise WindSpecError(f"wind spec is empty (expected {WIND_SPEC_HELP})")
    parts = []
    for i, part in enumerate(spec.split("+")):
        if not part.strip():
            raise WindSpecError(f"wind spec {spec!r}: empty part between '+'")
        parts.append(_parse_part(part.strip(), (seed, i)))
    return _combine(parts)


# --- the TOML table --------------------------------------------------------------------------


def wind_from_table(fields: Fields, seed: int = 0) -> WindField:
    """A wind from a TOML table; every key optional, an empty table is calm air::

        [wind]
        constant_ned_m_s = [3.0, 0.0, 0.0]   # steady part, NED m/s

        [wind.dryden]                        # mean wind + Dryden turbulence
        mean_speed_m_s = 5.0                 # W20, at 6 m
        direction_deg = 0.0                  # heading the air moves towards
        altitude_m = 10.0
        airspeed_m_s = 5.0                   # optional, default mean_speed_m_s

        [[wind.gusts]]                       # 1-cosine gusts, any number
        start_s = 10.0
        amplitude_m_s = 4.0
        duration_s = 2.0
        direction_deg = 90.0

    Raises
    ------
    ParameterFileError
        Naming the file and the field.
    """
    parts: list[WindField] = []
    if fields.has("constant_ned_m_s"):
        parts.append(ConstantWind(fields.vector("constant_ned_m_s", 3)))  # type: ignore[arg-type]
    if fields.has("dryden"):
        table = fields.sub("dryden")
        speed = table.number("mean_speed_m_s", ge=0)
        direction = table.number("direction_deg", 0.0)
        altitude = table.number("altitude_m", 10.0, gt=0)
        airspeed = table.number("airspeed_m_s", gt=0) if table.has("airspeed_m_s") else None
        table.reject_unknown()
        parts.append(DrydenTurbulence(speed, direction, altitude, airspeed, seed=(seed, 0)))
    if fields.has("gusts"):
        items = fields.raw("gusts")
        if not isinstance(items, list):
            raise fields.error("gusts", "expected an array of tables ([[wind.gusts]])")
        gusts = []
        for i, item in enumerate(items):
            table = Fields(item, fields.source, f"{fields.prefix}gusts[{i}].")
            gusts.append(
                Gust(
                    table.number("start_s"),
                    table.number("amplitude_m_s"),
                    table.number("duration_s", gt=0),
                    table.number("direction_deg", 0.0),
                )
            )
            table.reject_unknown()
        parts.append(GustWind(tuple(gusts)))
    fields.reject_unknown()
    return _combine(parts)
