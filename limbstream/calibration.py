"""Real sensors and the calibration that undoes them (docs/evaluation.md, "Calibration").

Sensor model. A strapped IMU reports, instead of its segment's orientation ``q`` (world <-
segment, the skeleton's frame: Y up), ``yaw(h + r t) * q * m``:

- ``m``: the mounting, the sensor's rotation on its segment (segment <- sensor), a random
  rotation of angle <= ``mounting_deg`` about a random axis;
- ``h``: its heading, the sensor's world frame turned about the vertical by a uniform
  +-``heading_deg`` (no magnetometer: headings are arbitrary);
- ``r``: its yaw drift, a uniform +-``yaw_drift_dps`` degrees per second (gyro bias).

Calibration script. A subject whose sensors are modelled begins with the rest pose (every
segment at identity: standing, or the T-pose for BVH) held still for :data:`REST_S`, then the
mounting pose (:data:`MOUNTING_PITCH_DEG`: every segment turned forward about the lateral axis)
held still for :data:`MOUNTING_S`, then the motion; the poses are joined by :data:`MOVE_S` of
SLERP.

Calibration, per device, a correction ``corrected = g * sensor * c``:

- ``rest`` (full reset, one still rest pose ``S0 = yaw(h) m``): ``c = S0^-1``, ``g`` = identity.
  Right for a device whose heading is 0; otherwise each orientation comes out conjugated by its
  heading: one pose cannot tell heading from the mounting's turn about the vertical.
- ``mounting`` (a second still pose of known orientation ``P``): the rest-corrected reading is
  ``yaw(h) P yaw(-h)``, whose rotation axis is ``P``'s turned by ``h`` about the vertical: that
  gives ``h``, and then ``g = yaw(-h)``, ``c = S0^-1 yaw(h)`` undo both.
- ``yaw`` (heading only, in the rest pose at any later time): the heading again from the
  mounting found before.

Quaternions are scalar-first (w, x, y, z), times seconds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from limbstream import quat
from limbstream.wire import SEGMENTS

VERTICAL = np.array([0.0, 1.0, 0.0])
"""The world's up axis (the skeleton's Y)."""
LATERAL = np.array([1.0, 0.0, 0.0])
"""The subject's left in the rest pose (the skeleton's X): the mounting pose's turning axis."""

REST_S = 3.0
"""The rest pose is held still this long at the start of the calibration script, s."""
MOUNTING_S = 2.0
"""... then the mounting pose, s."""
MOVE_S = 0.5
"""Each move between poses (rest -> mounting -> the motion's first frame), SLERP, s."""
STILL_MARGIN_S = 0.25
"""The still windows used by calibration leave this much out at each end, s."""
STILL_DEG = 2.0
"""A calibration is refused when a device turned more than this within its still window, deg."""
START_STILL_S = 1.0
"""A recording that starts in its rest pose holds it still at least this long, s: the window
:func:`calibrate_start` calibrates from."""

MOUNTING_PITCH_DEG = {"hip": 30.0, "neck": 30.0, "l_thigh": 60.0, "r_thigh": 60.0, "l_shank": 30.0,
                      "r_shank": 30.0, "l_upperarm": 60.0, "r_upperarm": 60.0, "l_lowerarm": 90.0,
                      "r_lowerarm": 90.0, "chest": 30.0, "head": 30.0, "l_hand": 90.0, "r_hand": 90.0,
                      "l_foot": 30.0, "r_foot": 30.0}
"""The mounting pose: each segment turned forward from its rest orientation about the lateral
axis by this much, degrees (a bow with bent knees and the arms raised forward, the hands in line
with the forearms, the heels raised; the pose must turn every segment about a horizontal axis, or
its heading cannot be told: a foot flat on the floor in both poses would not say where its toes
point)."""


def absent_segments(present, segments=SEGMENTS) -> list[str]:
    """The body's segments (``segments``, its layout's in order; default the 10-IMU layout's) not
    among ``present`` (segment names): what the calibration of a partial body leaves out."""
    present = set(present)
    return [s for s in segments if s not in present]


class CalibrationError(ValueError):
    """A calibration that cannot be made (device not still, bad samples): the sentence says why."""


def axis_angle(axis: np.ndarray, angle_rad: np.ndarray | float) -> np.ndarray:
    """(..., 4) rotation by ``angle_rad`` (...) about unit ``axis`` (..., 3) or (3,)."""
    half = 0.5 * np.asarray(angle_rad, np.float64)
    axis = np.asarray(axis, np.float64)
    return np.concatenate([np.cos(half)[..., None], np.sin(half)[..., None] * axis], axis=-1)


def yaw(angle_rad: np.ndarray | float) -> np.ndarray:
    """(..., 4) rotation about the vertical by ``angle_rad`` (...)."""
    return axis_angle(VERTICAL, angle_rad)


def yaw_of(q: np.ndarray) -> np.ndarray:
    """(...) the turn about the vertical of rotations ``q`` (..., 4) (twist of a swing-twist
    decomposition), radians in (-pi, pi]."""
    q = np.asarray(q, np.float64)
    return 2.0 * np.arctan2(q[..., 2], q[..., 0])


def mounting_pose(segments=SEGMENTS) -> np.ndarray:
    """(S, 4) each segment's orientation in the mounting pose (a segment not in
    :data:`MOUNTING_PITCH_DEG`, e.g. a foot, turns 30 degrees)."""
    # turning forward: the bone of a hanging limb (-Y) moves towards the subject's front (+Z)
    return axis_angle(LATERAL, -np.radians([MOUNTING_PITCH_DEG.get(s, 30.0) for s in segments]))


@dataclass(frozen=True)
class SensorModel:
    """Bounds of the sensor errors (all 0: perfect sensors, the sensor reports its segment)."""

    mounting_deg: float = 0.0
    heading_deg: float = 0.0
    yaw_drift_dps: float = 0.0
    seed: int = 0

    def __post_init__(self):
        for name, high in (("mounting_deg", 180.0), ("heading_deg", 180.0), ("yaw_drift_dps", 10.0)):
            value = getattr(self, name)
            if not 0.0 <= value <= high:
                raise ValueError(f"--{name.replace('_', '-')} must be in 0..{high:g}, got {value}")

    @property
    def on(self) -> bool:
        return self.mounting_deg > 0 or self.heading_deg > 0 or self.yaw_drift_dps > 0

    def draw(self, n: int, stream: int = 0) -> Sensors:
        """The errors of ``n`` sensors (seeded by ``seed`` and ``stream``)."""
        rng = np.random.default_rng([self.seed, stream])
        axis = rng.normal(size=(n, 3))
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        angle = np.radians(self.mounting_deg) * rng.uniform(0.0, 1.0, n)
        heading = np.radians(self.heading_deg) * rng.uniform(-1.0, 1.0, n)
        drift = np.radians(self.yaw_drift_dps) * rng.uniform(-1.0, 1.0, n)
        return Sensors(axis_angle(axis, angle), heading, drift)


@dataclass(frozen=True)
class Sensors:
    """Drawn sensor errors: ``mounting`` (n, 4), ``heading`` (n,) rad, ``drift`` (n,) rad/s."""

    mounting: np.ndarray
    heading: np.ndarray
    drift: np.ndarray

    def report_many(self, sensors: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(j, 4) float32 what sensors ``sensors`` (j,) report at times ``t`` (j,) s for their
        segments' orientations ``q`` (j, 4) (one sample each)."""
        h = yaw(self.heading[sensors] + self.drift[sensors] * np.asarray(t, np.float64))
        return quat.multiply(quat.multiply(h, np.asarray(q, np.float64)), self.mounting[sensors]).astype(np.float32)

    def report(self, k: int, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(m, 4) what sensor ``k`` reports for its segment's orientations ``q`` (m, 4) at times
        ``t`` (m,) s (from the sensor's start)."""
        h = yaw(self.heading[k] + self.drift[k] * np.asarray(t, np.float64))
        return quat.multiply(quat.multiply(h, np.asarray(q, np.float64)), self.mounting[k])


def with_script(q: np.ndarray, fs: float, segments=SEGMENTS) -> tuple[np.ndarray, slice, slice]:
    """A motion's orientations ``q`` (m, S, 4) of ``segments`` preceded by the calibration script
    at ``fs`` Hz.

    Returns
    -------
    q : (n, S, 4) the script, then the motion (its first sample at index ``n - m``).
    rest, mounting : the still windows (the rest and mounting pose held, less
        :data:`STILL_MARGIN_S` each side), as sample slices.
    """
    q = np.asarray(q, np.float64)
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (len(segments), 1))
    pose = mounting_pose(segments)
    n_rest, n_mount, n_move = (max(1, round(s * fs)) for s in (REST_S, MOUNTING_S, MOVE_S))
    u = np.repeat((np.arange(1, n_move + 1) / (n_move + 1))[:, None], len(segments), axis=1)  # (moves, S)
    parts = [np.broadcast_to(identity, (n_rest, *identity.shape)),
             quat.slerp(identity[None], pose[None], u),
             np.broadcast_to(pose, (n_mount, *pose.shape)),
             quat.slerp(pose[None], quat.normalize(q[:1]), u),
             q]
    margin = round(STILL_MARGIN_S * fs)
    rest = slice(margin, n_rest - margin)
    start = n_rest + n_move
    mounting = slice(start + margin, start + n_mount - margin)
    return np.concatenate([np.asarray(p, np.float64) for p in parts]), rest, mounting


class ScriptedFeed:
    """A feed (``segments``, ``sample(k) -> (S, 4)``, ``length``, ``rest_pose``,
    ``orientations``, ``body``) that starts with the calibration script: at the start of an endless feed
    (the generator), before every pass of a looped or finite one (a file)."""

    def __init__(self, feed, fs: float, loop_length: int | None = None):
        self.feed, self.segments, self.rest_pose = feed, feed.segments, feed.rest_pose
        self.orientations, self.body = feed.orientations, feed.body
        script, _, _ = with_script(np.asarray(feed.sample(0), np.float64)[None], fs, feed.segments)
        self.script = script[:-1].astype(np.float32)  # without the motion's first sample itself
        self.loop = loop_length  # samples per pass of a looped feed (None: endless or finite)
        n = len(self.script)
        self.length = None if feed.length is None else feed.length + n

    def sample(self, k: int) -> np.ndarray:
        n = len(self.script)
        if self.loop is not None:
            k_pass, k = divmod(k, self.loop + n)
            return self.script[k] if k < n else self.feed.sample(k_pass * self.loop + k - n)
        if self.length is not None and not 0 <= k < self.length:
            raise IndexError(f"sample {k} of a {self.length}-sample stream")
        return self.script[k] if k < n else self.feed.sample(k - n)


def still_mean(q: np.ndarray, what: str) -> np.ndarray:
    """(4,) the mean of a still window's orientations ``q`` (k, 4); CalibrationError (naming
    ``what``) if a sample is not a finite unit quaternion, or the device turned more than
    :data:`STILL_DEG` within it."""
    q = np.asarray(q, np.float64)
    if len(q) == 0:
        raise CalibrationError(f"{what}: no samples in the still window")
    norm = np.linalg.norm(q, axis=1)
    if not (np.all(np.isfinite(q)) and np.all(np.abs(norm - 1.0) < 1e-2)):
        raise CalibrationError(f"{what}: a sample in the still window is not a unit quaternion")
    q = q * np.where(q @ q[0] < 0, -1.0, 1.0)[:, None]  # one hemisphere
    mean = quat.normalize(q.mean(axis=0))
    turned = float(quat.angle_deg(q, np.broadcast_to(mean, q.shape)).max())
    if turned > STILL_DEG:
        raise CalibrationError(f"{what}: not still (turned {turned:.1f} deg within the pose, "
                               f"at most {STILL_DEG:g} allowed)")
    return mean


@dataclass(frozen=True)
class Calibration:
    """One device's correction ``g * sensor * c`` (each (4,): ``g`` turns the heading back,
    ``c`` undoes the mounting), what it was made from (``poses``) and its estimate of the sensor's
    mounting (segment <- sensor, (4,)) and heading (rad) at device time ``t_ref`` (s).

    Drift compensation: ``drift`` (rad/s) is the heading's rate learned from the last two heading
    measurements (a rest calibration or a yaw reset, then a yaw reset); given device times, the
    correction follows the heading ``heading + drift * (t - t_ref)`` instead of holding it
    (SlimeVR's server learns the same from successive resets)."""

    poses: tuple[str, ...]
    mounting: np.ndarray
    heading: float
    drift: float = 0.0
    t_ref: float = 0.0

    @property
    def g(self) -> np.ndarray:
        return yaw(-self.heading)

    @property
    def c(self) -> np.ndarray:
        return quat.conjugate(self.mounting)

    def as_dict(self) -> dict:
        """The calibration as JSON-ready values (:meth:`from_dict` reads them back)."""
        return {"poses": list(self.poses), "mounting": np.asarray(self.mounting).tolist(),
                "heading": self.heading, "drift": self.drift, "t_ref": self.t_ref}

    @staticmethod
    def from_dict(data: dict) -> Calibration:
        """The calibration of :meth:`as_dict`'s values; KeyError, TypeError or ValueError if bad."""
        mounting = np.array(data["mounting"], np.float64)
        if mounting.shape != (4,) or not np.isfinite(mounting).all():
            raise ValueError(f"mounting must be 4 finite numbers, got {data['mounting']!r}")
        return Calibration(tuple(str(p) for p in data["poses"]), quat.normalize(mounting), float(data["heading"]),
                           float(data.get("drift", 0.0)), float(data.get("t_ref", 0.0)))

    def _g(self, t) -> np.ndarray:
        """(4,) or (m, 4) the left factor at device times ``t`` (m,) s (None: at ``t_ref``)."""
        if t is None or self.drift == 0.0:
            return self.g
        return yaw(-(self.heading + self.drift * (np.asarray(t, np.float64) - self.t_ref)))

    def apply(self, q: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
        """(m, 4) the segment orientations of sensor readings ``q`` (m, 4) taken at device times
        ``t`` (m,) s (needed for drift compensation only)."""
        return quat.multiply(quat.multiply(self._g(t), np.asarray(q, np.float64)), self.c)

    def undo(self, q: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
        """(m, 4) the sensor readings of corrected orientations ``q`` (m, 4) at device times ``t``."""
        return quat.multiply(quat.multiply(quat.conjugate(self._g(t)), np.asarray(q, np.float64)),
                             quat.conjugate(self.c))

    @staticmethod
    def none() -> Calibration:
        return Calibration((), np.array([1.0, 0.0, 0.0, 0.0]), 0.0)

    @staticmethod
    def rest(s0: np.ndarray, t: float = 0.0) -> Calibration:
        """Full reset from the still rest-pose reading ``s0`` (4,) at device time ``t`` s: heading
        taken as 0."""
        s0 = quat.normalize(np.asarray(s0, np.float64))
        return Calibration(("rest",), s0, 0.0, 0.0, float(t))

    def with_mounting(self, reading: np.ndarray, pose: np.ndarray) -> Calibration:
        """Resolve the heading from a still reading ``reading`` (4,) of the known pose ``pose``
        (4,), after a rest calibration (and any since); CalibrationError if the pose turns about
        the vertical only. The heading found is the one at the rest reading (``t_ref`` stays):
        the mounting pose only tells heading from mounting."""
        if "rest" not in self.poses:
            raise CalibrationError("mounting: calibrate the rest pose first")
        if self.poses != ("rest",):  # start again from the rest reading this calibration implies
            base = Calibration.rest(quat.multiply(yaw(self.heading), self.mounting), self.t_ref)
            return base.with_mounting(reading, pose)
        seen = self.apply(np.asarray(reading, np.float64)[None])[0]  # yaw(h) pose yaw(-h)
        want, got = _horizontal_axis(pose), _horizontal_axis(seen)
        if want is None or got is None:
            raise CalibrationError("mounting: the pose turned the device about the vertical only; "
                                   "its heading cannot be told")
        h = math.atan2(want[0] * got[1] - want[1] * got[0], want @ got)  # turn from want to got
        s0 = self.mounting  # the rest reading yaw(h) m
        mounting = quat.multiply(yaw(-h), s0)
        return Calibration(self.poses + ("mounting",), mounting, h, 0.0, self.t_ref)

    def with_yaw(self, reading: np.ndarray, t: float | None = None, learn_drift: bool = True) -> Calibration:
        """Heading reset from a still rest-pose reading ``reading`` (4,) at device time ``t`` s,
        keeping the mounting found before; with ``t`` (and ``learn_drift``) the drift is learned
        from the heading measured at ``t_ref`` and this one (unwrapped about the heading the
        current drift predicts, so that long intervals keep whole turns)."""
        heading_rot = quat.multiply(quat.normalize(np.asarray(reading, np.float64)), quat.conjugate(self.mounting))
        h = float(yaw_of(heading_rot))
        drift, t_ref = self.drift, self.t_ref
        if t is not None:
            t = float(t)
            dt = t - self.t_ref
            if learn_drift and dt > 0:
                predicted = self.heading + self.drift * dt
                drift = (predicted + math.remainder(h - predicted, math.tau) - self.heading) / dt
            t_ref = t
        return Calibration(self.poses + ("yaw",), self.mounting, h, drift if learn_drift else 0.0, t_ref)


def _horizontal_axis(q: np.ndarray) -> np.ndarray | None:
    """The horizontal direction (x, z) of rotation ``q``'s axis, sign fixed by a positive angle;
    None if the rotation is (nearly) about the vertical or none."""
    q = np.asarray(q, np.float64)
    v = q[1:] * (1.0 if q[0] >= 0 else -1.0)  # sin(angle / 2) * axis, angle in [0, pi]
    flat = np.array([v[2], v[0]])  # (z, x): angles measured from +Z towards +X, as yaw turns Z
    norm = float(np.linalg.norm(flat))
    return None if norm < math.sin(math.radians(5.0) / 2) else flat / norm


def calibrate(q: np.ndarray, rest: slice, mounting: slice | None, pose: np.ndarray | None,
              what: str = "device", t: np.ndarray | None = None) -> Calibration:
    """A device's calibration from its readings ``q`` (m, 4) in the still windows: ``rest`` (rest
    pose) and, if given, ``mounting`` (the known ``pose`` (4,)); ``t`` (m,) their device times, s
    (the heading's time for drift compensation later; None: unknown)."""
    cal = Calibration.rest(still_mean(q[rest], f"{what}, rest pose"), _middle(t, rest))
    if mounting is not None and pose is not None:
        cal = cal.with_mounting(still_mean(q[mounting], f"{what}, mounting pose"), pose)
    return cal


def calibrate_start(q: np.ndarray, fs: float, segments, still_s: float = START_STILL_S) -> np.ndarray:
    """(m, S, 4) the segment orientations of readings ``q`` (m, S, 4) at ``fs`` Hz of sensors on
    ``segments`` whose first ``still_s`` seconds are the rest pose held still: each sensor's full
    reset (``rest``) from that window. CalibrationError naming the first sensor that is not still
    there."""
    q = np.asarray(q, np.float64)
    window = slice(0, max(1, round(still_s * fs)))
    return np.stack([calibrate(q[:, k], window, None, None, segment).apply(q[:, k])
                     for k, segment in enumerate(segments)], axis=1)


def _middle(t: np.ndarray | None, window: slice) -> float:
    """The device time (s) in the middle of a still window (0 without times)."""
    return 0.0 if t is None else float(np.mean(np.asarray(t, np.float64)[window]))
