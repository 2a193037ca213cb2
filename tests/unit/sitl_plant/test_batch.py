"""The fast steppers of ``sitl_plant.dynamics.batch`` against the reference equations.

Every kernel must give what ``rigid_body.derivative`` / ``integrate.rk4_step`` /
``VehicleSim`` give for the same inputs (to 1e-12), whether numba compiles it or not.
"""

from __future__ import annotations

import numpy as np
import pytest

from sitl_plant.dynamics import batch, rigid_body
from sitl_plant.dynamics.integrate import rk4_step
from sitl_plant.dynamics.rigid_body import RigidBodyModel
from sitl_plant.dynamics.wind import wind_from_spec
from sitl_plant.simulation import EulerAccelActuation, HeldActuation, VehicleSim
from offboard.model.vehicle import VehicleParams

DRAGGY = VehicleParams(linear_drag_n_s_m=(0.12, 0.12, 0.25))
INSTANT = VehicleParams(motor_time_constant_s=0.0, rotor_speed_min_rad_s=50.0)


def random_states(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 17))
    x[:, 6:10] /= np.linalg.norm(x[:, 6:10], axis=1, keepdims=True)
    x[:, 13:17] = 250.0 + 200.0 * rng.random((n, 4))
    cmd = rng.uniform(-50.0, 800.0, size=(n, 4))  # some outside the speed limits: clipped
    wind = rng.normal(scale=3.0, size=(n, 3))
    return x, cmd, wind


@pytest.mark.parametrize("params", [DRAGGY, INSTANT], ids=["motor-lag-drag", "instant-motors"])
@pytest.mark.parametrize("n", [1, 5, 33, 200])  # below, at and across the kernel's block size
def test_derivative_many_equals_reference(params: VehicleParams, n: int) -> None:
    x, cmd, wind = random_states(n)
    got = batch.derivative_many(x, cmd, wind, params)
    want = np.array([rigid_body.derivative(x[i], cmd[i], wind[i], params) for i in range(n)])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("params", [DRAGGY, INSTANT], ids=["motor-lag-drag", "instant-motors"])
def test_step_many_equals_rk4_step(params: VehicleParams) -> None:
    x, cmd, wind = random_states(70, seed=3)
    got = batch.step_many(x.copy(), cmd, wind, params, 1e-3, n_steps=3)
    want = x.copy()
    for i in range(len(x)):
        for _ in range(3):
            f = lambda s, i=i: rigid_body.derivative(s, cmd[i], wind[i], params)  # noqa: E731
            want[i] = rigid_body.normalize(rk4_step(f, want[i], 1e-3))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(got[:, 6:10], axis=1), 1.0, atol=1e-14)


def test_numpy_path_equals_compiled_path() -> None:
    x, cmd, wind = random_states(50, seed=9)
    a = batch.step_many(x.copy(), cmd, wind, DRAGGY, 1e-3, n_steps=2)
    b = batch.step_many_numpy(x.copy(), cmd, wind, DRAGGY, 1e-3, n_steps=2)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_step_many_broadcasts_shared_inputs() -> None:
    x, _, _ = random_states(10, seed=5)
    cmd, wind = np.full(4, 360.0), np.array([1.0, -2.0, 0.5])
    got = batch.step_many(x.copy(), cmd, wind, DRAGGY, 2e-3)
    want = batch.step_many(x.copy(), np.tile(cmd, (10, 1)), np.tile(wind, (10, 1)), DRAGGY, 2e-3)
    np.testing.assert_array_equal(got, want)


def test_step_many_refuses_a_wrong_layout() -> None:
    x, cmd, wind = random_states(4)
    with pytest.raises(ValueError, match="C-contiguous float64"):
        batch.step_many(np.asfortranarray(x), cmd, wind, DRAGGY, 1e-3)
    with pytest.raises(ValueError):
        batch.step_many(x[:, :12].copy(), cmd, wind, DRAGGY, 1e-3)


def test_param_vector_order() -> None:
    p = batch.param_vector(DRAGGY)
    assert p.shape == (14,)
    assert p[0] == DRAGGY.mass_kg and p[10] == DRAGGY.thrust_coeff_n_s2 and p[13] == DRAGGY.motor_time_constant_s
    np.testing.assert_array_equal(p[4:7], DRAGGY.inertia_kg_m2)
    np.testing.assert_array_equal(p[7:10], DRAGGY.linear_drag_n_s_m)


class TiltingActuation:
    """A Python actuation (not one the kernels know): torque from the state, as an attitude loop."""

    def __call__(self, model: RigidBodyModel, x: np.ndarray) -> tuple[float, np.ndarray]:
        return 5.5, np.array([0.02 - 0.05 * x[10], -0.01 - 0.05 * x[11], 0.001 - 0.02 * x[12]])


def _fly(sim: VehicleSim | batch.FastRigidBodySim, actuations: list) -> list[np.ndarray]:
    states = []
    for act in actuations:
        sim.actuation = act
        sim.step(50)
        truth = sim.truth()
        states.append(np.concatenate([sim.x, truth.acc_ned_m_s2, [sim.time_s, float(truth.on_ground)]]))
    return states


@pytest.mark.parametrize("wind", ["none", "dryden:5+gust:t=0.3,amp=4,dur=0.4"])
def test_fast_sim_flies_as_vehicle_sim(wind: str) -> None:
    """Take-off from the ground, each actuation kind, wind: the same flight to rounding."""
    believed = np.diag([2.7e-3, 4.8e-3, 8.9e-3])
    actuations = [
        HeldActuation(0.0, np.zeros(3)),  # resting on the ground
        HeldActuation(8.0, np.array([0.001, -0.002, 0.0005])),  # lift-off
        HeldActuation(8.0, np.array([0.0, 0.0, 0.0])),
        EulerAccelActuation(5.2, np.array([0.8, -0.5, 0.3]), believed, "zyx"),
        EulerAccelActuation(4.6, np.array([-1.0, 0.4, -0.2]), believed, "castillo"),
        TiltingActuation(),
        EulerAccelActuation(19.0, np.array([30.0, 0.0, 0.0]), believed, "zyx"),  # saturates the mixer
    ]
    runs = []
    for cls in (VehicleSim, batch.FastRigidBodySim):
        sim = cls(RigidBodyModel(DRAGGY), wind=None if wind == "none" else wind_from_spec(wind, 7))
        runs.append(_fly(sim, actuations))
    reference, fast = runs
    assert reference[0][-1] == 1.0 and reference[2][-1] == 0.0 and reference[-1][2] < -0.1  # rested, flew
    for want, got in zip(reference, fast):
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10)


def test_fast_sim_refuses_other_models() -> None:
    from sitl_plant.simulation import PaperModel

    with pytest.raises(TypeError):
        batch.FastRigidBodySim(PaperModel(DRAGGY))  # type: ignore[arg-type]


class _PerStep:
    """The same Px4Loop seen as a plain actuation (no ``held``): called at every physics step."""

    def __init__(self, loop) -> None:  # noqa: ANN001
        self.loop = loop

    def __call__(self, model, x):  # noqa: ANN001, ANN204
        return self.loop(model, x)


def test_px4_loop_held_steps_equal_per_step_calls() -> None:
    """FastRigidBodySim flies the PX4 attitude and rate loops compiled with the physics
    (px4_kernel): the flight, the loop's integrators and output are bit for bit those of the
    Python loop called at every step, and VehicleSim's to rounding."""
    from sitl_plant.inner_loops import Px4Loop
    from sitl_plant.params import plant_params

    def flight(cls, held: bool) -> np.ndarray:  # noqa: ANN001
        model = RigidBodyModel(DRAGGY)
        sim = cls(model, initial_pos_ned_m=np.array([0.0, 0.0, -3.0]))
        loop = Px4Loop(plant_params(DRAGGY), model, 1e-3)
        loop.landed = False
        out = []
        for i, (q, thrust) in enumerate([((1.0, 0.0, 0.0, 0.0), 6.0), ((0.995, 0.0998, 0.0, 0.0), 5.5),
                                         ((0.98, 0.0, 0.15, 0.13), 5.0), (None, 5.2)] * 3):  # fmt: skip
            if q is None:
                loop.fly_rates((0.3, -0.2, 0.1), thrust)
            else:
                loop.fly_attitude(q, thrust, 0.2 * (i % 2))
            sim.actuation = loop if held else _PerStep(loop)
            sim.step(50 if i % 2 else 47)  # also periods that are not a whole number of gyro samples
            out.append(np.concatenate([sim.x, [sim.time_s, loop._step_count, *loop._rate_int, loop.last_output[0]],
                                       loop.last_output[1]]))  # fmt: skip
        return np.array(out)

    held = flight(batch.FastRigidBodySim, True)
    np.testing.assert_array_equal(held, flight(batch.FastRigidBodySim, False))
    np.testing.assert_allclose(held, flight(VehicleSim, True), rtol=1e-10, atol=1e-10)
    assert abs(held[-1, 0]) + abs(held[-1, 1]) > 0.01  # it flew somewhere


def test_plant_steps_compiled_only_from_a_warm_cache(tmp_path) -> None:
    """A plant never compiles at start-up (seconds of silence): with numba's cache cold it flies
    the reference VehicleSim; once the kernels are compiled, the compiled one."""
    import os
    import subprocess
    import sys

    from sitl_plant import px4_kernel
    from sitl_plant.server import make_model, make_sim

    code = ("from sitl_plant.server import make_model, make_sim; from offboard.model.vehicle import VehicleParams; "
            "print(type(make_sim(make_model('rigid-body', VehicleParams()), 1e-3, None)).__name__)")  # fmt: skip
    cold = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)})  # fmt: skip
    assert cold.stdout.strip() == "VehicleSim", cold.stderr
    px4_kernel.compile_all()
    sim = make_sim(make_model("rigid-body", VehicleParams()), 1e-3, None)
    assert type(sim).__name__ == ("FastRigidBodySim" if batch.NUMBA else "VehicleSim")
    assert type(make_sim(make_model("paper", VehicleParams()), 1e-3, None)).__name__ == "VehicleSim"


def test_a_kernel_cache_older_than_a_source_built_into_it_is_stale(tmp_path) -> None:
    """numba keys a module's cached kernels to that module's file only: ``stale_cache_files`` finds
    the module's cache files older than the newest source compiled into them (px4_kernel's hold
    batch's physics), which ``drop_stale_cache`` removes at import so numba compiles them again."""
    import os

    cache = tmp_path / "__pycache__"
    cache.mkdir()
    dep = tmp_path / "batch.py"
    dep.write_text("# the physics")
    names = ["px4_kernel._qmul-29.py311.nbi", "px4_kernel._qmul-29.py311.1.nbc", "batch._rates-10.py311.nbi",
             "px4_kernel.cpython-311.pyc"]  # fmt: skip
    for name in names:
        (cache / name).write_bytes(b"")
    old = os.path.getmtime(dep) - 60.0
    for name in names:
        os.utime(cache / name, (old, old))
    stale = sorted(os.path.basename(p) for p in batch.stale_cache_files(cache, "px4_kernel", (str(dep),)))
    assert stale == sorted(names[:2])  # its own kernels' index and data; not another module's, not the .pyc
    new = os.path.getmtime(dep) + 60.0
    os.utime(cache / names[0], (new, new))
    assert [os.path.basename(p) for p in batch.stale_cache_files(cache, "px4_kernel", (str(dep),))] == [names[1]]
    assert batch.stale_cache_files(tmp_path / "absent", "px4_kernel", (str(dep),)) == []


@pytest.mark.skipif(not batch.NUMBA, reason="numba is not installed: nothing is cached")
def test_a_kernel_is_cached_for_its_sources_content_not_its_files_time(tmp_path) -> None:
    """``is_cached`` asks numba's own index: a source touched (or checked out again) unchanged is
    still cached, as numba loads it; a changed source is not. (A test of the files' times said no
    to the first, and the plant, which flies compiled only when ``compiled_ready``, then ran
    interpreted for good: numba loaded the cache and never wrote its index again.)"""
    import os
    import subprocess
    import sys

    module = tmp_path / "kernel_probe.py"
    module.write_text("import numba\n\n@numba.njit(cache=True)\ndef add_one(x):\n    return x + 1\n")
    probe = ("import sys; sys.path.insert(0, sys.argv[1]); import kernel_probe; from sitl_plant.dynamics import batch; "
             "call = sys.argv[2] == 'call'; call and kernel_probe.add_one(1); print(batch.is_cached(kernel_probe.add_one))")  # fmt: skip

    def cached(call: bool = False) -> str:
        run = subprocess.run([sys.executable, "-c", probe, str(tmp_path), "call" if call else "look"], capture_output=True,
                             text=True, timeout=120, env={k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"})  # fmt: skip
        assert run.returncode == 0, run.stderr
        return run.stdout.strip()

    assert cached() == "False"  # never compiled
    assert cached(call=True) == "True"  # compiled and saved
    later = os.path.getmtime(module) + 60.0
    os.utime(module, (later, later))  # touched: newer than the cache, the same source
    assert cached() == "True"
    module.write_text(module.read_text() + "\n# changed\n")
    os.utime(module, (later + 60.0, later + 60.0))
    assert cached() == "False"
