"""Speed: the controller's step, the physics (one vehicle and a batch), each next to its floor or peer.

Every figure is a median of repeated measurements taken in the same run as its comparison.
"""

from __future__ import annotations

import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from offboard.controller import ControllerParams, LawMemory, RosalesController, TrackingReference, law_step

ROOT = Path(__file__).resolve().parents[1]


def _median_us(fn, calls: int, repeats: int) -> float:  # noqa: ANN001
    """Median over ``repeats`` batches of the mean time of one call in a batch of ``calls``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - start) / calls)
    return statistics.median(times) * 1e6


# --- the same law solved with numpy's pseudo-inverse (eq. 34-35) ---------------------------------


def pinv_law_step(params: ControllerParams, memory: LawMemory, x: tuple, ref_n: TrackingReference,
                  ref_n1: TrackingReference) -> tuple[np.ndarray, LawMemory]:  # fmt: skip
    """One sample of the law with ``w = A+ b`` (eq. 35) instead of the closed form (eq. 39-42).

    Eq. 31-34 give the increments and eq. 28-29 the angles exactly as ``law_step``; then eq. 34 is
    stacked as ``A w = b`` with ``w = (u, tau~phi, tau~theta, tau~psi)`` and solved with
    ``numpy.linalg.pinv``. (The paper's law as published: yaw-free, no limits.)
    """
    k, to, m, g = params.gains, params.sample_time_s, params.mass_kg, params.gravity_m_s2
    xv = np.asarray(x, dtype=float)
    pos = xv[[0, 2, 4]]
    vel = xv[[1, 3, 5]]
    ref0 = np.array([ref_n.x_m, ref_n.y_m, ref_n.z_up_m])
    ref1 = np.array([ref_n1.x_m, ref_n1.y_m, ref_n1.z_up_m])
    kx = np.array([k.kx1, k.kx3, k.kx5])
    kv = np.array([k.kx2, k.kx4, k.kx6])
    vd = (ref1 - kx * (ref0 - pos) - pos) / to  # eq. 32
    d = vd - kv * (np.array([memory.x2d, memory.x4d, memory.x6d]) - vel) - vel  # eq. 33-34
    yaw_err0 = (ref_n.yaw_rad - xv[10] + math.pi) % (2 * math.pi) - math.pi
    yaw_err1 = (ref_n1.yaw_rad - xv[10] + math.pi) % (2 * math.pi) - math.pi
    x12d = (yaw_err1 - k.kx11 * yaw_err0) / to
    vertical = d[2] + g * to
    sign = math.copysign(1.0, vertical)
    phi = math.atan2(d[1] * sign, vertical * sign)  # eq. 28
    theta = math.atan2(-d[0] * math.cos(phi) * sign, vertical * sign)  # eq. 29, non-singular form
    x8d = (phi - k.kx7 * (memory.x7ez - xv[6]) - xv[6]) / to
    x10d = (theta - k.kx9 * (memory.x9ez - xv[8]) - xv[8]) / to
    rate_refs = np.array([x8d - k.kx8 * (memory.x8d - xv[7]), x10d - k.kx10 * (memory.x10d - xv[9]),
                          x12d - k.kx12 * (memory.x12d - xv[11])])  # fmt: skip
    a = np.zeros((6, 4))  # eq. 34 with the angles of eq. 28-29
    a[:3, 0] = [-math.sin(theta) / m, math.cos(theta) * math.sin(phi) / m, math.cos(theta) * math.cos(phi) / m]
    a[3:, 1:] = np.eye(3)
    b = np.concatenate([[d[0], d[1], vertical], rate_refs - xv[[7, 9, 11]]]) / to
    w = np.linalg.pinv(a) @ b  # eq. 35
    return w, LawMemory(vd[0], vd[1], vd[2], x8d, x10d, x12d, phi, theta)


def controller_step(calls: int, repeats: int) -> dict:
    """Median µs of one sample: ``law_step`` (floats), ``RosalesController.step``, and the pinv law."""
    paper = ControllerParams()  # the paper's law as published, to compare with the pinv solution
    x = (0.3, 0.5, -0.2, 0.1, 1.0, 0.2, 0.05, 0.01, -0.03, 0.02, 0.4, 0.05)
    memory = LawMemory.from_state(x)
    ref_n, ref_n1 = TrackingReference(0.5, -0.1, 1.4, 0.5), TrackingReference(0.55, -0.08, 1.44, 0.52)
    out, _ = law_step(paper, memory, x, ref_n, ref_n1)
    w, _ = pinv_law_step(paper, memory, x, ref_n, ref_n1)
    agree = float(np.max(np.abs(w - np.array([out.thrust_n, *out.tau_tilde]))))
    bench_params = ControllerParams(yaw_aware=True, euler_rate_form="zyx")
    ctrl = RosalesController(bench_params)
    ctrl.step(x, ref_n, ref_n1)
    return {
        "law_step_us": _median_us(lambda: law_step(paper, memory, x, ref_n, ref_n1), calls, repeats),
        "law_step_yaw_aware_limits_us": _median_us(
            lambda: law_step(_BENCH_LIMITED, memory, x, ref_n, ref_n1), calls, repeats
        ),
        "controller_step_us": _median_us(lambda: ctrl.step(x, ref_n, ref_n1), calls, repeats),
        "pinv_us": _median_us(lambda: pinv_law_step(paper, memory, x, ref_n, ref_n1), max(1, calls // 5), repeats),
        "pinv_max_difference": agree,
    }


def _limited() -> ControllerParams:
    from offboard.controller import ActionLimits

    return ControllerParams(
        yaw_aware=True, euler_rate_form="zyx",
        limits=ActionLimits(thrust_min_n=0.0, thrust_max_n=19.6, tilt_max_rad=math.radians(35)),
    )  # fmt: skip


_BENCH_LIMITED = _limited()


# --- physics: one vehicle ---------------------------------------------------------------------------


def _helix():
    from offboard.missions import MISSIONS_DIR, load_mission

    return load_mission(MISSIONS_DIR / "paper-helix.toml").trajectory


FAST_REPEATS = 5


def physics_one_vehicle(duration_s: float, reference_duration_s: float, rotorpy_duration_s: float) -> dict:
    """Sim-s per wall-s of the helix flight (paper's law at 20 Hz, 1 kHz RK4), three ways."""
    from bench.flight import fly
    from bench.pilots import NOMINAL, contender
    from sitl_plant.dynamics import batch
    from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    trajectory = _helix()
    fly(*contender("paper", NOMINAL), trajectory, vehicle, duration_s=0.2)  # compile / warm caches
    rates, physics_rates = [], []
    for _ in range(FAST_REPEATS):  # the median of a few flights: one is a few tens of ms
        start = time.perf_counter()
        fast = fly(*contender("paper", NOMINAL), trajectory, vehicle, duration_s=duration_s)
        rates.append(duration_s / (time.perf_counter() - start))
        physics_rates.append(duration_s / fast.physics_wall_s)
    fast_rate = statistics.median(rates)
    start = time.perf_counter()
    ref = fly(*contender("paper", NOMINAL), trajectory, vehicle, duration_s=reference_duration_s, fast=False)
    ref_rate = reference_duration_s / (time.perf_counter() - start)
    n = len(ref.t_s)
    deviation = float(np.max(np.abs(ref.pos_ned_m - fast.pos_ned_m[:n])))
    result = {
        "fast_x_realtime": fast_rate,
        "fast_physics_only_x_realtime": statistics.median(physics_rates),
        "vehicle_sim_physics_only_x_realtime": reference_duration_s / ref.physics_wall_s,
        "vehicle_sim_x_realtime": ref_rate,
        "max_position_difference_m": deviation,
        "numba": batch.NUMBA,
        "flight_s": duration_s,
        "reference_flight_s": reference_duration_s,
    }
    result["no_numba_x_realtime"] = _no_numba_rate(min(2.0, duration_s))
    result.update(_rotorpy_rate(rotorpy_duration_s, vehicle, trajectory))
    return result


def _no_numba_rate(duration_s: float) -> float | None:
    """The same fast loop with the kernels interpreted (SITL_PLANT_NO_NUMBA=1), in a subprocess."""
    code = (
        "import sys,time; sys.path.insert(0, %r)\n"
        "from bench.flight import fly; from bench.pilots import contender, NOMINAL\n"
        "from bench.speed import _helix\n"
        "from offboard.model.vehicle import load_vehicle, PAPER_VEHICLE_FILE\n"
        "v = load_vehicle(PAPER_VEHICLE_FILE); tr = _helix()\n"
        "s = time.perf_counter(); fly(*contender('paper', NOMINAL), tr, v, duration_s=%r)\n"
        "print(%r / (time.perf_counter() - s))\n"
    ) % (str(ROOT), duration_s, duration_s)
    env = dict(os.environ, SITL_PLANT_NO_NUMBA="1")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    if proc.returncode != 0:
        return None
    return float(proc.stdout.strip().splitlines()[-1])


def rotorpy_quad_params(vehicle) -> dict:  # noqa: ANN001
    """Our vehicle in RotorPy's ``quad_params`` (FLU body): the "+" layout, no aerodynamics."""
    arm = vehicle.arm_length_m
    ixx, iyy, izz = vehicle.inertia_kg_m2
    return {
        "mass": vehicle.mass_kg, "Ixx": ixx, "Iyy": iyy, "Izz": izz, "Ixy": 0.0, "Iyz": 0.0, "Ixz": 0.0,
        "num_rotors": 4, "rotor_radius": 0.1,
        # f1 right, f2 front, f3 left, f4 rear: in FLU, right is -y
        "rotor_pos": {"r1": np.array([0.0, -arm, 0.0]), "r2": np.array([arm, 0.0, 0.0]),
                      "r3": np.array([0.0, arm, 0.0]), "r4": np.array([-arm, 0.0, 0.0])},
        # FRD yaw torque c(f2 + f4 - f1 - f3) about down = c(f1 + f3 - f2 - f4) about up
        "rotor_directions": np.array([1, -1, 1, -1]),
        "rI": np.zeros(3), "c_Dx": 0.0, "c_Dy": 0.0, "c_Dz": 0.0,
        "k_eta": vehicle.thrust_coeff_n_s2, "k_m": vehicle.drag_to_thrust_m * vehicle.thrust_coeff_n_s2,
        "k_d": 0.0, "k_z": 0.0, "k_h": 0.0, "k_flap": 0.0,
        "tau_m": vehicle.motor_time_constant_s,
        "rotor_speed_min": vehicle.rotor_speed_min_rad_s, "rotor_speed_max": vehicle.rotor_speed_max_rad_s,
        "motor_noise_std": 0.0, "k_w": 1, "k_v": 10, "kp_att": 544, "kd_att": 46.64,
    }  # fmt: skip


def _rotorpy_rate(duration_s: float, vehicle, trajectory) -> dict:  # noqa: ANN001
    """RotorPy's ``Multirotor`` stepping the same flight: same law at 20 Hz, same eq. 16 inner loop
    and mixer at 1 kHz (computed here), its ``step`` (solve_ivp) for the physics."""
    try:
        from rotorpy.vehicles.multirotor import Multirotor
        from scipy.spatial.transform import Rotation
    except ImportError:
        return {"rotorpy": None}
    from importlib import metadata

    from bench.pilots import NOMINAL, contender
    from offboard.inprocess import vehicle_loop
    from sitl_plant.dynamics.rigid_body import hover_rotor_speed, rotor_speeds_for
    from offboard.model.rotations import euler_from_quat
    from offboard.model.state import VehicleState

    flu = np.diag([1.0, -1.0, -1.0])
    ned_enu = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    ref0 = trajectory.reference(0.0)
    r0 = ned_enu @ np.eye(3) @ flu  # level, yaw from the reference below
    from offboard.model.rotations import quat_from_euler, rotation_matrix

    r0 = ned_enu @ rotation_matrix(quat_from_euler(0.0, 0.0, ref0.yaw_rad)) @ flu
    speed = hover_rotor_speed(vehicle)
    state = {"x": ned_enu @ ref0.pos_ned_m, "v": np.zeros(3), "q": Rotation.from_matrix(r0).as_quat(),
             "w": np.zeros(3), "wind": np.zeros(3), "rotor_speeds": np.full(4, speed)}  # fmt: skip
    quad = Multirotor(rotorpy_quad_params(vehicle), initial_state=state, control_abstraction="cmd_motor_speeds",
                      aero=False, enable_ground=False)  # fmt: skip
    controller, drive = contender("paper", NOMINAL)
    inner_loop = vehicle_loop(drive, controller, vehicle)
    samples = int(round(duration_s / 0.05))
    physics_s = 0.0
    errors = []
    start = time.perf_counter()
    for n in range(samples):
        t = n * 0.05
        r = ned_enu @ Rotation.from_quat(state["q"]).as_matrix() @ flu
        w = flu @ state["w"]
        q = _quat_wxyz(r)
        eta = euler_from_quat(q)
        vel = ned_enu @ state["v"]
        measured = VehicleState(t, ned_enu @ state["x"], vel, np.zeros(3), eta, np.zeros(3), w, q)
        errors.append(float(np.linalg.norm(measured.pos_ned_m - trajectory.reference(t).pos_ned_m)))
        act = inner_loop.actuation(controller.step(measured, trajectory.reference(t), trajectory.reference(t + 0.05)), None)  # type: ignore[arg-type]
        model = _EulerReader()
        for _ in range(50):
            r = ned_enu @ Rotation.from_quat(state["q"]).as_matrix() @ flu
            model.set(_quat_wxyz(r), flu @ state["w"])
            thrust, torque = act(model, None)
            cmd = rotor_speeds_for(thrust, torque, vehicle)
            s0 = time.perf_counter()
            state = quad.step(state, {"cmd_motor_speeds": cmd}, 0.001)
            physics_s += time.perf_counter() - s0
    wall = time.perf_counter() - start
    return {
        "rotorpy": metadata.version("rotorpy"),
        "rotorpy_x_realtime": duration_s / wall,
        "rotorpy_physics_only_x_realtime": duration_s / physics_s,
        "rotorpy_flight_s": duration_s,
        "rotorpy_rms_error_m": float(np.sqrt(np.mean(np.square(errors)))),
    }


def _quat_wxyz(r: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(r).as_quat()
    return np.array([w, x, y, z])


class _EulerReader:
    """Enough of ``RigidBodyModel`` for ``EulerAccelActuation`` on RotorPy's state."""

    def set(self, q: np.ndarray, w: np.ndarray) -> None:
        self.q, self.w = q, w

    def euler(self, x: object) -> tuple[np.ndarray, np.ndarray]:
        from offboard.model.euler_lagrange import zyx_euler_rates_from_body_rates
        from offboard.model.rotations import euler_from_quat

        eta = euler_from_quat(self.q)
        return eta, zyx_euler_rates_from_body_rates(eta, self.w)

    def torque_from_generalized(self, x: object, tau: np.ndarray) -> np.ndarray:
        from offboard.model.euler_lagrange import zyx_body_torque_from_generalized
        from offboard.model.rotations import euler_from_quat

        return zyx_body_torque_from_generalized(euler_from_quat(self.q), tau)


# --- physics: many vehicles ---------------------------------------------------------------------------


def physics_batch(sizes: list[int], steps: int, numpy_max: int) -> list[dict]:
    """Vehicle-steps per second of ``step_many`` (compiled) and ``step_many_numpy`` by batch size."""
    from sitl_plant.dynamics import batch
    from sitl_plant.dynamics.rigid_body import hover_rotor_speed
    from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

    vehicle = load_vehicle(PAPER_VEHICLE_FILE).with_changes(linear_drag_n_s_m=(0.12, 0.12, 0.2))
    rng = np.random.default_rng(0)
    rows = []
    warm = np.zeros((40, 17))
    warm[:, 6] = 1.0
    batch.step_many(warm, np.full(4, 350.0), np.zeros(3), vehicle, 1e-3, 1)  # compile
    for n in sizes:
        x = np.zeros((n, 17))
        x[:, 2] = -10.0
        x[:, 6] = 1.0
        x[:, 13:17] = hover_rotor_speed(vehicle)
        cmd = hover_rotor_speed(vehicle) + rng.uniform(-5, 5, (n, 4))
        wind = rng.normal(size=(n, 3))
        k = max(1, steps // max(1, n // 1000))  # fewer steps for big batches, same work order
        row = {"vehicles": n, "steps": k, "numpy_per_s": None}
        row["compiled_per_s"] = n * k / _best_s(lambda xs: batch.step_many(xs, cmd, wind, vehicle, 1e-3, k), x, 3)
        if n <= numpy_max:
            kn = max(1, min(k, 20))
            row["numpy_per_s"] = n * kn / _best_s(lambda xs: batch.step_many_numpy(xs, cmd, wind, vehicle, 1e-3, kn), x, 2)
        rows.append(row)
    return rows


def _best_s(step, x: np.ndarray, repeats: int) -> float:  # noqa: ANN001
    """Shortest wall time of ``step`` on a fresh copy of the batch ``x`` over ``repeats`` tries."""
    best = math.inf
    for _ in range(repeats):
        xs = x.copy()
        start = time.perf_counter()
        step(xs)
        best = min(best, time.perf_counter() - start)
    return best


def numba_compile_s() -> float:
    """Wall time to import ``dynamics.batch`` and run each of its kernels once (``step_many``,
    ``derivative_many``, ``advance_many`` in its per-vehicle and blocked forms) in a fresh process
    with numba's cache warm: the snippet runs once first, in another process, so that the figure
    never includes a compilation (at c456dc1 it did: ``derivative_many``, which nothing before it
    in the run had called, compiled inside the timed process, 14.8 s against 0.6 s before)."""
    code = (
        "import time; s=time.perf_counter()\n"
        "from sitl_plant.dynamics import batch\n"
        "batch.compile_many()\n"
        "print(time.perf_counter()-s)\n"
    )
    for _ in range(2):  # the first compiles what the cache lacks; the second is the figure
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900, cwd=ROOT)
        if proc.returncode != 0:
            return math.nan
    return float(proc.stdout.strip().splitlines()[-1])
