"""VRChat output: a real ``limbstream vrchat`` process behind a real router, emulator and
aggregator, sending to a real python-osc UDP server; and the convention (Unity's Euler order,
the mirror, units) checked against constructions written here independently."""
from __future__ import annotations

import signal
import threading

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from limbstream import quat, wire, zconfig
from limbstream.cli import main
from limbstream.skeleton import Skeleton
from limbstream.services.outputs import vrchat
from support.osc import OscReceiver
from support.stack import wait_for_subscribers, wait_until

MIRROR = np.diag([-1.0, 1.0, 1.0])  # Unity (x right) <-> limbstream (x left)
NAMES = {t.name: k for k, t in enumerate(vrchat.TRACKERS)}


def axis_angle(axis: str, deg: float) -> np.ndarray:
    """Scalar-first rotation by ``deg`` about the unit axis X, Y or Z (Unity's AngleAxis)."""
    v = {"X": [1, 0, 0], "Y": [0, 1, 0], "Z": [0, 0, 1]}[axis]
    h = np.radians(deg) / 2
    return np.array([np.cos(h), *(np.sin(h) * np.array(v, float))])


def unity_euler(x: float, y: float, z: float) -> np.ndarray:
    """Unity's Quaternion.Euler(x, y, z): z about Z, then x about X, then y about Y (world axes)."""
    return quat.multiply(quat.multiply(axis_angle("Y", y), axis_angle("X", x)), axis_angle("Z", z))


def frame_of(q: np.ndarray, flags: int = 0) -> wire.PoseFrame:
    q = np.asarray(q, np.float32)
    return wire.PoseFrame(0, 0, wire.KIND_LIVE, flags, q, Skeleton().positions(q))


IDENTITY = np.tile([1.0, 0.0, 0.0, 0.0], (10, 1))


def test_euler_angles_are_unitys_order():
    rng = np.random.default_rng(4)
    for x, y, z in zip(rng.uniform(-89, 89, 200), rng.uniform(-179, 179, 200), rng.uniform(-179, 179, 200)):
        got = quat.unity_euler_deg(unity_euler(x, y, z))
        assert np.abs(got - [x, y, z]).max() < 1e-9


def test_mirror_is_m_r_m():
    q = quat.normalize(np.random.default_rng(5).normal(size=(50, 4)))
    want = MIRROR @ quat.to_rotation(q).as_matrix() @ MIRROR
    assert np.abs(quat.to_rotation(quat.mirror_x(q)).as_matrix() - want).max() < 1e-12


def test_identity_pose_stands_on_the_floor_unrotated():
    positions, rotations = vrchat.tracker_values(frame_of(IDENTITY))
    assert np.abs(rotations).max() == 0.0
    p = {name: positions[k] for name, k in NAMES.items()}
    assert 0.8 <= p["hip"][1] <= 1.2
    assert p["left foot"][1] == p["right foot"][1] == pytest.approx(0.0, abs=1e-6)
    assert 0.0 < p["left knee"][1] < p["hip"][1] < p["chest"][1] < p["head"][1]
    assert p["left elbow"][1] > p["left knee"][1]
    # the subject's left is +x in limbstream's frame and -x (Unity's x points right) in VRChat's
    left = Skeleton().positions(IDENTITY.astype(np.float32))[wire.JOINTS.index("l_knee")]
    assert left[0] > 0
    for side in ("foot", "knee", "elbow"):
        assert p[f"left {side}"][0] == pytest.approx(-Skeleton().hip_width / 2 if side != "elbow"
                                                     else -Skeleton().shoulder_width / 2, abs=1e-6)
        assert p[f"right {side}"][0] == -p[f"left {side}"][0]


def test_turning_left_is_a_negative_yaw_and_the_lower_foot_is_on_the_floor():
    left90 = quat.multiply(axis_angle("Y", 90.0), IDENTITY)  # all segments: facing +X, the subject's left
    positions, rotations = vrchat.tracker_values(frame_of(left90))
    assert np.abs(rotations - [0.0, -90.0, 0.0]).max() < 1e-4  # Unity: +y turns to the right
    assert positions[NAMES["hip"], 1] == pytest.approx(0.88, abs=1e-5)
    knee_up = IDENTITY.copy()
    knee_up[wire.SEGMENTS.index("l_thigh")] = axis_angle("X", -90.0)  # left thigh forward (+Z)
    positions, _ = vrchat.tracker_values(frame_of(knee_up))
    assert positions[NAMES["right foot"], 1] == pytest.approx(0.0, abs=1e-6)
    assert positions[NAMES["left foot"], 1] == pytest.approx(0.45, abs=1e-5)  # knee height - shank
    assert positions[NAMES["left knee"], 2] == pytest.approx(0.45, abs=1e-5)  # forward stays +Z


def test_a_bad_frame_is_counted_and_a_missing_segment_does_not_stop_it():
    receiver = OscReceiver()
    sender = vrchat.VrchatSender("s01", ("127.0.0.1", receiver.port))
    try:
        assert not sender.send(frame_of(np.zeros((10, 4)), wire.FRAME_MISSING))
        assert sender.send(frame_of(IDENTITY, wire.FRAME_MISSING))
        assert (sender.counters.sent, sender.counters.bad) == (1, 1)
        wait_until(lambda: len(receiver.snapshot()) >= len(vrchat.ADDRESSES), 10, "one frame's messages")
        assert [a for a, _ in receiver.snapshot()] == list(vrchat.ADDRESSES)
    finally:
        sender.close()
        receiver.close()


class PoseFrames:
    """(kind, flags, t_us) of a subject's pose frames, as published, in arrival order."""

    def __init__(self, endpoint: str, subject: str):
        self.frames: list[tuple[int, int, int]] = []
        self.lock = threading.Lock()
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.sub = self.session.declare_subscriber(wire.pose_key(subject), self._add)

    def _add(self, sample):
        frame = wire.decode_pose(bytes(sample.payload))
        with self.lock:
            self.frames.append((frame.kind, frame.flags, frame.t_us))

    def live(self) -> list[tuple[int, int]]:
        """(flags, t_us) of the live frames."""
        with self.lock:
            return [(flags, t) for kind, flags, t in self.frames if kind == wire.KIND_LIVE]

    def exact_before_live(self) -> int:
        """Exact frames that came before the first live one (shown while no live frame came)."""
        with self.lock:
            kinds = [kind for kind, _, _ in self.frames]
        return kinds.index(wire.KIND_LIVE) if wire.KIND_LIVE in kinds else len(kinds)

    def close(self):
        self.sub.undeclare()
        self.session.close()


def per_frame(messages: list[tuple[str, list]]) -> list[dict[str, np.ndarray]]:
    """Messages grouped per frame: address -> (3,) values, each group starting at tracker 1."""
    out: list[dict[str, np.ndarray]] = []
    for address, args in messages:
        if address == vrchat.ADDRESSES[0]:
            out.append({})
        if out:
            out[-1][address] = np.array(args, float)
    return [f for f in out if len(f) == len(vrchat.ADDRESSES)]


def test_vrchat_process_on_the_live_stack(stack):
    """Every live frame of the aggregator (fed by the emulator) becomes one set of tracker
    messages, at the frame rate (per second of frame time); a device that vanishes (frames
    flagged MISSING) does not stop it; Ctrl-C does, cleanly."""
    stack.router()
    receiver = OscReceiver()
    child = stack.start("vrchat", "vrchat", "--subject", "s01", "--to", f"127.0.0.1:{receiver.port}",
                        "--connect", stack.endpoint, "--wait", "0")
    wait_for_subscribers(stack.endpoint, [wire.pose_key("s01")], "vrchat to subscribe")
    published = PoseFrames(stack.endpoint, "s01")  # both subscribed before any frame is published
    hip = vrchat.ADDRESSES[0]
    try:
        emulator = stack.emulator(1, 1.0)
        aggregator = stack.aggregator()
        wait_until(lambda: len(published.live()) >= 100, 60, "100 live frames", on_fail=lambda: print(stack.logs()))
        emulator.signal(signal.SIGINT)  # the devices vanish: live frames go on, flagged MISSING
        wait_until(lambda: any(flags & wire.FRAME_MISSING for flags, _ in published.live()[100:]), 60,
                   "a live frame flagged MISSING", on_fail=lambda: print(stack.logs()))
        aggregator.signal(signal.SIGINT)
        wait_until(lambda: not aggregator.alive(), 30, "the aggregator to stop")
        live = published.live()
        expected = len(live) + published.exact_before_live()
        assert child.alive()
        child.signal(signal.SIGINT)
        wait_until(lambda: not child.alive(), 30, "vrchat to stop on Ctrl-C")
        assert child.returncode == 0
        assert not any("Traceback" in line for line in child.tail())
        said = next((line for line in child.tail() if " frames sent, 0 bad frames" in line), None)
        assert said is not None, child.tail()
        sent = int(said.split("limbstream vrchat: ")[1].split(" frames sent")[0])
        # every frame it took is one set of messages; live frames are DROP frames (superseded 20 ms
        # later), so on a loaded machine the router may drop some on vrchat's link
        assert 0.5 * expected <= sent <= expected, (sent, expected)
        wait_until(lambda: receiver.count(hip) >= sent, 30, f"{sent} frames' messages",
                   on_fail=lambda: print(receiver.count(hip), stack.logs()))
        assert receiver.count(hip) == sent
    finally:
        published.close()
        receiver.close()
    span_s = (live[-1][1] - live[0][1]) / 1e6
    rate = (sent - published.exact_before_live() - 1) / span_s  # per second of frame time
    print(f"{len(live)} live frames over {span_s:.2f} s of frame time: {rate:.1f} tracker sets/s ({sent} sent)")
    assert rate <= 1.1 * wire.DEVICE_RATE_HZ  # the aggregator's --live-rate (50 Hz), under load less
    messages = receiver.snapshot()
    assert {a for a, _ in messages} == set(vrchat.ADDRESSES)
    assert all(len(args) == 3 and all(isinstance(v, float) for v in args) for _, args in messages)
    frames = per_frame(messages)
    assert len(frames) == sent

    def position(f, n):
        return f[f"/tracking/trackers/{vrchat.TRACKERS[NAMES[n]].address}/position"]

    for f in frames:
        hip_y = position(f, "hip")[1]
        feet_y = [position(f, "left foot")[1], position(f, "right foot")[1]]
        assert 0.8 <= hip_y <= 1.2
        # the aggregator's root translation stands the lowest heel on the floor: a foot tracker, at its
        # ankle, is up to the ankle's height above it (paper10's default body: 0.068 m)
        assert -1e-6 <= min(feet_y) <= 0.1 and max(feet_y) < 0.5
        for side in ("left", "right"):
            assert min(feet_y) < position(f, f"{side} knee")[1] < hip_y
        # handedness: in the pelvis's own frame (its Unity Euler angles undone), the left knee is
        # on Unity's -x side of the right one (the subject's left is +x in limbstream's frame)
        turn = Rotation.from_euler("YXZ", f["/tracking/trackers/1/rotation"][[1, 0, 2]], degrees=True)
        left, right = turn.inv().apply([position(f, "left knee") - position(f, "hip"),
                                        position(f, "right knee") - position(f, "hip")])
        assert left[0] < right[0]


def _run(argv, capsys) -> tuple[int, str]:
    code = main(["vrchat", *argv])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("argv, flag", [
    ([], "--subject"),
    (["--subject", "s/1"], "--subject s/1"),
    (["--subject", "s01", "--to", "127.0.0.1"], "--to 127.0.0.1"),
    (["--subject", "s01", "--to", "127.0.0.1:70000"], "--to 127.0.0.1:70000"),
    (["--subject", "s01", "--to", "no.such.host.invalid:9000"], "--to no.such.host.invalid:9000"),
    (["--subject", "s01", "--wait", "-1"], "--wait"),
])
def test_bad_flags_are_one_line_errors(argv, flag, capsys):
    code, err = _run(argv, capsys)
    assert code == 2
    assert err.count("\n") == 1 and err.startswith(f"limbstream vrchat: error: {flag}"), err


def test_trackers_walk_with_the_frames_root():
    """A frame carrying a root: each tracker at its joint plus the root (world position), mirrored
    x -> -x; a root of zeros with a contact set is a root (the pelvis on the floor), and the same
    frame without a root stands on its feet instead."""
    import dataclasses
    still = frame_of(IDENTITY)
    stood, _ = vrchat.tracker_values(still)
    joints = np.asarray(still.joints, np.float64)
    root = np.array([0.7, 0.85, -1.5])
    positions, rotations = vrchat.tracker_values(dataclasses.replace(still, root=np.float32(root), contacts=0b0011))
    p = {name: positions[k] for name, k in NAMES.items()}
    for name, joint in (("hip", "pelvis"), ("left knee", "l_knee"), ("right foot", "r_ankle"), ("head", "head")):
        want = (joints[wire.JOINTS.index(joint)] + root) * [-1.0, 1.0, 1.0]
        assert p[name] == pytest.approx(want, abs=1e-6), name
    assert np.abs(rotations).max() == 0.0
    on_floor, _ = vrchat.tracker_values(dataclasses.replace(still, contacts=0b0001))
    assert on_floor[NAMES["hip"]] == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    assert stood[NAMES["hip"], 1] == pytest.approx(0.88, abs=1e-5)
