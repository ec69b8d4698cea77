"""FMI 2.0 co-simulation export (`phc export --fmu`), checked in a real importer: FMPy.

What is compared with what:

* an FMU and `phc simulate` with the same solver (implicit midpoint) and the same steps run
  the same C step loop (phc/codegen/c_runtime/steps.c) on the same functions from the same
  start: they agree to 1e-10 relative (in practice to round-off: the start state and the
  time grid are computed in two places, phc's ``np.linspace`` and FMPy's ``t0 + k*dt``);
* a parameter set from FMPy changes the FMU's result as the same `--param` changes phc's;
* an input driven from FMPy (a force on a mass-spring-damper, sampled and held over each
  communication step by FMPy) against scipy's solution of the same held input, at two steps:
  the error falls by 4 when the step halves (the midpoint rule's order 2);
* the energy balance H(t) - H(t0) + E(t) the FMU reports stays at round-off level (the
  midpoint rule's discrete energy balance);
* what cannot be exported is refused with one line naming the file.

Skipped only without a C compiler (the FMU's binary is built with it).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fmpy
from fmpy.validation import validate_fmu

import phc
from phc.codegen import c_backend
from phc.export import ExportError, export_fmu

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "models"

_CC, _WHY = c_backend.available()
pytestmark = pytest.mark.skipif(not _CC, reason=f"no C compiler to build an FMU's binary: {_WHY}")

SAME_CODE = 1e-10
"""Relative agreement of the FMU and `phc simulate`: the same steps of the same compiled code;
only the start state's and the time grid's round-off differ (observed: 1e-15)."""


MSD_FORCE = """\
format_version: 1
name: msd_force
description: mass-spring-damper pushed by a force source (the FMU's input)
parameters:
  m: {value: 1.0, unit: kg, description: mass}
  k: {value: 4.0, unit: N/m, description: stiffness}
  c: {value: 0.4, unit: N*s/m, description: damping}
components:
  mass: {type: mass, m: m}
  spring: {type: spring, k: k}
  damper: {type: damper, d: c}
  force: {type: effort_source, domain: mechanical.translational, value: 0}
  node:
    type: junction
    kind: common_flow
    domain: mechanical.translational
    ports: [to_mass, to_spring, to_damper, to_force]
connections:
  - [node.to_mass, mass.port]
  - [node.to_spring, spring.port]
  - [node.to_damper, damper.port]
  - [node.to_force, force.port]
simulation:
  t_end: 10.0
  n_out: 1001
  initial:
    spring.x: 0.0
    mass.p: 0.0
  outputs:
    x: spring.x
    v: mass.p / m
"""


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """Exported once per module: {name: (fmu path, report)}."""
    folder = tmp_path_factory.mktemp("fmus")
    made = {}

    def get(name: str, model, **options):
        if name not in made:
            out = folder / f"{name}.fmu"
            made[name] = (str(out), export_fmu(model, out, certify=False, **options))
        return made[name]

    return get


def _phc(model, t_end, dt, **options):
    compiled = phc.compile_model(model, certify=False)
    n_out = int(round(t_end / dt)) + 1
    return phc.simulate(compiled, solver="midpoint", t_end=t_end, n_out=n_out, backend="c", **options)


def _relative(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


@pytest.mark.parametrize("name, model", [("pendulum", MODELS / "pendulum.yaml"),
                                         ("rlc", MODELS / "rlc_circuit.yaml")])
def test_fmpy_validates_the_fmu(fmus, name, model):
    path, report = fmus(name, model)
    assert validate_fmu(path) == []
    assert report.unknowns > 0 and "energy.balance_error" in report.outputs


def test_pendulum_matches_phc_simulate(fmus):
    path, report = fmus("pendulum", MODELS / "pendulum.yaml")
    assert report.step == 0.0  # the model has no simulation.step: one step per communication interval
    t_end, dt = 4.0, 0.01
    got = fmpy.simulate_fmu(path, stop_time=t_end, output_interval=dt,
                            output=["angle", "pendulum.x", "pendulum.y", "energy.H", "energy.balance_error"])
    ref = _phc(MODELS / "pendulum.yaml", t_end, dt)
    assert len(got) == len(ref.t)
    assert np.allclose(got["time"], ref.t, rtol=0, atol=1e-12)
    assert _relative(got["angle"], ref.outputs["angle"]) < SAME_CODE
    j = list(ref.variables).index("pendulum.x")
    assert _relative(got["pendulum.x"], ref.y[:, j]) < SAME_CODE
    assert _relative(got["pendulum.y"], ref.y[:, j + 1]) < SAME_CODE
    # H and the balance: the pendulum's H swings through 0 (V = m g y), so against the energy scale m g L
    scale = 9.81
    assert np.abs(got["energy.H"] - ref.H).max() < SAME_CODE * scale
    # the discrete energy balance per step to the Newton tolerance (1e-14 relative) over 400 steps
    assert np.abs(got["energy.balance_error"]).max() < 1e-11 * scale


def test_rlc_matches_phc_simulate(fmus):
    path, report = fmus("rlc", MODELS / "rlc_circuit.yaml")
    assert report.inputs == ("source",)
    t_end, dt = 2.0, 0.005
    got = fmpy.simulate_fmu(path, stop_time=t_end, output_interval=dt,
                            output=["charge", "current", "capacitor_voltage", "energy.H", "energy.balance_error"])
    ref = _phc(MODELS / "rlc_circuit.yaml", t_end, dt)
    for name in ("charge", "current", "capacitor_voltage"):
        assert _relative(got[name], ref.outputs[name]) < SAME_CODE, name
    assert _relative(got["energy.H"], ref.H) < SAME_CODE
    # supplied and dissipated energy booked per step: the balance at round-off of H's size
    assert np.abs(got["energy.balance_error"]).max() < 1e-12 * ref.H.max()


@pytest.mark.parametrize("name, model, parameter, value, output, t_end, dt", [
    ("pendulum", MODELS / "pendulum.yaml", "g", 3.0, "angle", 2.0, 0.01),
    ("rlc", MODELS / "rlc_circuit.yaml", "R", 5.0, "charge", 2.0, 0.005),
])
def test_parameter_set_in_fmpy_acts_as_in_phc(fmus, name, model, parameter, value, output, t_end, dt):
    path, report = fmus(name, model)
    assert parameter in report.parameters and parameter not in report.fixes_start
    default = fmpy.simulate_fmu(path, stop_time=t_end, output_interval=dt, output=[output])
    changed = fmpy.simulate_fmu(path, stop_time=t_end, output_interval=dt, output=[output],
                                start_values={parameter: value})
    ref = _phc(model, t_end, dt, params={parameter: value})
    assert _relative(changed[output], ref.outputs[output]) < SAME_CODE
    assert _relative(changed[output], default[output]) > 1e-2  # it did change the result


def test_parameter_the_start_depends_on_is_refused_with_a_logged_error(fmus, capsys):
    path, report = fmus("pendulum", MODELS / "pendulum.yaml")
    assert report.fixes_start == ("L",)  # the start x = L is written in it
    # FMPy's own logger prints the FMU's messages (a logger of the test's would stay installed in
    # FMPy's process-wide logger proxy after the test and be called once freed)
    with pytest.raises(Exception, match="fmi2ExitInitializationMode"):
        fmpy.simulate_fmu(path, stop_time=0.1, output_interval=0.01, start_values={"L": 2.0})
    errors = [line for line in capsys.readouterr().out.splitlines() if line.startswith("[ERROR]")]
    assert len(errors) == 1 and "`L`" in errors[0] and "--param L=2" in errors[0], errors


def test_exported_with_param_starts_where_phc_starts(tmp_path):
    """The remedy the refusal names: `phc export --param L=2` makes an FMU whose start (x = L) and
    run are phc's with L = 2."""
    out = tmp_path / "long.fmu"
    done = _cli(MODELS / "pendulum.yaml", "--fmu", out, "--param", "L=2", "--no-certify")
    assert done.returncode == 0 and done.stdout.startswith(f"{out}: FMI 2.0 co-simulation FMU"), done.stderr
    got = fmpy.simulate_fmu(str(out), stop_time=1.0, output_interval=0.01, output=["angle", "pendulum.x"])
    ref = _phc(MODELS / "pendulum.yaml", 1.0, 0.01, params={"L": 2.0})
    assert got["pendulum.x"][0] == 2.0
    assert _relative(got["angle"], ref.outputs["angle"]) < SAME_CODE


def _held_input_solution(t_grid, u, m, k, c, x0=0.0, v0=0.0):
    """x(t) of m x'' + c x' + k x = u_j on [t_j, t_j+1) (the input held over each communication
    step), by scipy at tolerances far below the midpoint rule's error."""
    from scipy.integrate import solve_ivp

    state, xs = np.array([x0, v0]), [x0]
    for j in range(len(t_grid) - 1):
        def rhs(t, s, f=u[j]):
            return [s[1], (f - c * s[1] - k * s[0]) / m]
        sol = solve_ivp(rhs, (t_grid[j], t_grid[j + 1]), state, method="DOP853", rtol=1e-13, atol=1e-15)
        state = sol.y[:, -1]
        xs.append(state[0])
    return np.array(xs)


def test_input_driven_from_fmpy_matches_scipy_at_order_two(fmus, tmp_path):
    model = tmp_path / "msd_force.yaml"
    model.write_text(MSD_FORCE, encoding="utf-8")
    t_end, dt = 5.0, 0.01
    t = np.round(np.arange(0.0, t_end + dt / 2, dt), 12)
    signal = np.zeros(len(t), dtype=[("time", float), ("force", float)])
    signal["time"], signal["force"] = t, np.sin(1.5 * t) + 0.5
    exact = _held_input_solution(t, signal["force"], 1.0, 4.0, 0.4)
    errors = []
    for h in (2e-3, 1e-3):
        path, report = fmus(f"msd_{h:g}", model, step=h)
        assert report.inputs == ("force",)
        got = fmpy.simulate_fmu(path, stop_time=t_end, output_interval=dt, input=signal,
                                output=["x", "energy.H", "energy.balance_error"])
        assert len(got) == len(t)
        errors.append(np.abs(got["x"] - exact).max())
        # the work of the force and the damper's loss booked per step: the balance at round-off
        assert np.abs(got["energy.balance_error"]).max() < 1e-12 * got["energy.H"].max()
    assert 3.6 < errors[0] / errors[1] < 4.4, errors  # order 2
    # and of the size of the midpoint rule's phase error, h² ω³ T / 24 of the amplitude (ω = 2)
    assert errors[1] < 4 * (1e-3) ** 2 * 2.0 ** 3 * t_end / 24 * np.abs(exact).max()


def test_two_instances_in_one_process_do_not_share_state(fmus, tmp_path):
    """The generated C is re-entrant: two instances of one binary, stepped in turn with different
    parameters, give each what it gives alone."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    path, _ = fmus("pendulum", MODELS / "pendulum.yaml")
    unzipped = extract(path, unzipdir=str(tmp_path / "unzipped"))  # one copy: both run in one loaded library
    md = read_model_description(unzipped)
    vr = {v.name: v.valueReference for v in md.modelVariables}

    def start(name, g):
        s = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName=name)
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setReal([vr["g"]], [g])
        s.exitInitializationMode()
        return s

    a, b = start("a", 9.81), start("b", 3.0)
    angles = {"a": [], "b": []}
    time = 0.0
    for k in range(100):
        after = 0.0 + (k + 1) * 0.01  # FMPy's communication points
        for name, s in (("a", a), ("b", b)):
            s.doStep(currentCommunicationPoint=time, communicationStepSize=after - time)
            angles[name].append(s.getReal([vr["angle"]])[0])
        time = after
    for s in (a, b):
        s.terminate()
        s.freeInstance()
    for name, g in (("a", 9.81), ("b", 3.0)):
        alone = fmpy.simulate_fmu(path, stop_time=1.0, output_interval=0.01, output=["angle"],
                                  start_values={"g": g})
        # the same steps: equal to round-off (state shared between instances would differ at O(1))
        np.testing.assert_allclose(angles[name], alone["angle"][1:], rtol=1e-13, atol=1e-15)


def _slave(path, tmp_path, name="a"):
    """An FMU2Slave of the exported FMU, instantiated, and its value references by name."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    unzipped = extract(path, unzipdir=str(tmp_path / f"unzipped_{name}"))
    md = read_model_description(unzipped)
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName=name)
    slave.instantiate()
    return slave, {v.name: v.valueReference for v in md.modelVariables}, md


def _steps(slave, vr, names, t0, t1, dt):
    """Step from t0 to t1 at FMPy's communication points; the values of `names` after each step."""
    rows, n = [], int(round((t1 - t0) / dt))
    for k in range(n):
        t, after = t0 + k * dt, t0 + (k + 1) * dt
        slave.doStep(currentCommunicationPoint=t, communicationStepSize=after - t)
        rows.append(slave.getReal([vr[name] for name in names]))
    return np.array(rows)


def test_tunable_parameter_changed_between_steps(fmus, tmp_path):
    """R of the RLC circuit changed at t = 1 (tunable: the start does not depend on it): the FMU
    continues as phc does when started from the state at t = 1 with the new R (the circuit is
    autonomous; the predictor's history differs, so agreement is to the Newton tolerance)."""
    path, _ = fmus("rlc", MODELS / "rlc_circuit.yaml")
    slave, vr, md = _slave(path, tmp_path)
    assert {v.name: v.variability for v in md.modelVariables}["R"] == "tunable"
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    names = ["inductor.phi", "capacitor.q", "charge", "energy.balance_error", "energy.H"]
    dt = 0.005
    first = _steps(slave, vr, names, 0.0, 1.0, dt)
    slave.setReal([vr["R"]], [5.0])
    second = _steps(slave, vr, names, 1.0, 2.0, dt)
    slave.terminate()
    slave.freeInstance()
    ref = _phc(MODELS / "rlc_circuit.yaml", 1.0, dt, params={"R": 5.0},
               initial={"inductor.phi": float(first[-1, 0]), "capacitor.q": float(first[-1, 1])})
    assert _relative(second[:, 2], ref.outputs["charge"][1:]) < SAME_CODE
    # R is not in H: nothing to book; the balance stays at round-off of H across the change
    both = np.concatenate([first, second])
    assert np.abs(both[:, 3]).max() < 1e-12 * np.abs(both[:, 4]).max()


def test_tuning_a_parameter_in_the_energy_books_the_jump(fmus, tmp_path):
    """The pendulum's mass changed at t = 0.5: H jumps with it (p²/2m + m g y), the jump is the
    work of the change, booked, so energy.balance_error stays the method's (round-off)."""
    path, _ = fmus("pendulum", MODELS / "pendulum.yaml")
    slave, vr, _ = _slave(path, tmp_path)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    names = ["energy.H", "energy.balance_error"]
    before = _steps(slave, vr, names, 0.0, 0.5, 0.01)
    slave.setReal([vr["m"]], [2.0])
    after = _steps(slave, vr, names, 0.5, 1.0, 0.01)
    with pytest.raises(Exception):  # L: the start depends on it, so it is fixed
        slave.setReal([vr["L"]], [2.0])
    slave.terminate()
    slave.freeInstance()
    # H did jump: 0 before; the kinetic part halved, the potential doubled
    assert abs(after[0, 0] - before[-1, 0]) > 1.0
    assert np.abs(np.concatenate([before[:, 1], after[:, 1]])).max() < 1e-11 * 9.81


def test_fmu_c_compiles_cleanly_and_exports_only_fmi_functions(fmus, tmp_path):
    """fmu.c (with steps.c and fmi2_cs.c) under -Wall -Wextra -pedantic -Werror; the binary's
    dynamic symbols are the FMI functions alone (the model's and the step loop's stay hidden)."""
    import zipfile

    path, report = fmus("pendulum", MODELS / "pendulum.yaml")
    with zipfile.ZipFile(path) as zf:
        zf.extractall(tmp_path)
        names = zf.namelist()
    assert {"modelDescription.xml", "sources/model.c", "sources/fmu.c", "sources/steps.c", "sources/fmi2_cs.c",
            f"binaries/linux64/{report.identifier}.so"} <= set(names)
    argv, _ = c_backend.find_compiler()
    done = subprocess.run([*argv, "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-c", "-o", "fmu.o", "fmu.c"],
                          cwd=tmp_path / "sources", capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    import ctypes

    lib = ctypes.CDLL(str(tmp_path / "binaries" / "linux64" / f"{report.identifier}.so"))
    assert lib.fmi2DoStep and lib.fmi2Instantiate
    for hidden in ("phc_residual", "phc_steps_chunk", "derived_parameters"):
        with pytest.raises(AttributeError):
            getattr(lib, hidden)


def _cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "phc", "export", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, env={**os.environ, **(env or {})}, timeout=600)


@pytest.mark.parametrize("args, env, says", [
    (["--solver", "ida"], None, "implicit midpoint rule"),
    (["--fmi", "3"], None, "FMI 3 is not offered"),
    ([], {"CC": "/nonexistent/cc"}, "no C compiler found"),
])
def test_export_mistakes_are_one_located_line(tmp_path, args, env, says):
    done = _cli(MODELS / "pendulum.yaml", "--fmu", tmp_path / "p.fmu", *args, env=env)
    lines = done.stderr.strip().splitlines()
    assert done.returncode != 0 and len(lines) == 1, done.stderr
    assert lines[0].startswith(str(MODELS / "pendulum.yaml") + ":") and says in lines[0]
    assert "Traceback" not in done.stderr and not (tmp_path / "p.fmu").exists()


def test_model_with_events_is_refused(tmp_path):
    with pytest.raises(ExportError, match="switching conditions|breakpoints") as err:
        export_fmu(MODELS / "dc_motor_gear.yaml", tmp_path / "m.fmu", certify=False)
    assert str(err.value).startswith(str(MODELS / "dc_motor_gear.yaml") + ":")
    assert not (tmp_path / "m.fmu").exists()


def test_a_failing_build_of_the_binary_is_one_line_naming_the_compilers_error(tmp_path):
    """The FMU's binary is built by the C back end's compiler runner (phc.codegen.cc): a compile
    error is one ExportError line with the compiler's first error line, and no binary is left."""
    from phc.export.fmu import _build

    argv, _ = c_backend.find_compiler()
    (tmp_path / "sources").mkdir()
    (tmp_path / "sources" / "model.c").write_text("double f(double x) { return x; }\n")
    (tmp_path / "sources" / "fmu.c").write_text("int g(void)\n{\n    return 1 +;\n}\n")  # error on line 3
    with pytest.raises(ExportError) as err:
        _build(tmp_path, "broken", argv)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"the C compiler ({argv[0]}) failed on the FMU's sources (exit ")
    assert "a phc bug: please report it): fmu.c:3:" in message
    assert not (tmp_path / "binaries" / "linux64" / "broken.so").exists()


def test_flexible_slider_crank_matches_phc_simulate(fmus):
    model = MODELS / "flexible_slider_crank.yaml"
    path, report = fmus("fsc", model)
    assert validate_fmu(path) == []
    t_end, dt = 0.01, 5e-4  # 1000 steps of the model's 1e-5
    outputs = ["theta", "slider_x", "midspan_deflection", "crank_speed"]
    got = fmpy.simulate_fmu(path, stop_time=t_end, output_interval=dt, output=outputs + ["energy.H"])
    ref = _phc(model, t_end, dt)
    for name in outputs:
        assert _relative(got[name], ref.outputs[name]) < SAME_CODE, name
    assert _relative(got["energy.H"], ref.H) < SAME_CODE
