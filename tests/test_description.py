"""The compiled-model contract (phc.codegen.description, phc.codegen.compiled): a compiled model's
description round-trips through JSON, cannot be changed, and is all a run reads — a model
loaded from it (the cached front end, phc.codegen.fastpath) runs bit for bit as the full path."""

from __future__ import annotations

import dataclasses
import pickle
from pathlib import Path

import numpy as np
import pytest

import phc
from phc.codegen import fastpath
from phc.cli import _written_options, build_parser
from phc.codegen.compiled import CompiledModel, RunCache
from phc.codegen.description import ModelDescription

REPO = Path(__file__).resolve().parents[1]
PENDULUM = REPO / "models" / "pendulum.yaml"
SCENE = REPO / "models" / "scenes" / "slider_crank_rigid.yaml"


@pytest.fixture(scope="module")
def pendulum() -> CompiledModel:
    return phc.compile_model(PENDULUM)


@pytest.fixture(scope="module")
def scene() -> CompiledModel:
    return phc.compile_model(SCENE)


def _same_run(a, b) -> None:
    for key in ("t", "y", "yp", "H", "energy_supplied", "invariants"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
    assert a.outputs.keys() == b.outputs.keys()
    for name in a.outputs:
        assert np.array_equal(a.outputs[name], b.outputs[name]), name
    assert (a.steps, a.n_residual_evals, a.message) == (b.steps, b.n_residual_evals, b.message)


@pytest.mark.parametrize("which", ["pendulum", "scene"])
def test_json_round_trip_equals_the_original(which, request):
    compiled = request.getfixturevalue(which)
    desc = compiled.description
    text = desc.to_json()
    back = ModelDescription.from_json(text)
    assert back == desc
    assert back.to_json() == text
    assert pickle.loads(pickle.dumps(desc)) == desc  # pickled through its JSON text
    # what the description holds is what the compiler produced
    assert desc.name == compiled.name and desc.n_states == compiled.dae.n_states - 1
    assert [eq.label for eq in desc.equations] == [eq.label for eq in compiled.dae.equations]
    assert desc.outputs == tuple(compiled.module.OUTPUTS)
    assert dict(desc.options) == dict(compiled.dae.options)
    assert desc.certificate is not None and desc.certificate.certified
    assert desc.certificate.summary == compiled.certificate.summary()


def test_a_scene_description_names_its_scene_and_what_it_left_out(scene):
    desc = scene.description
    assert desc.scene is not None and desc.scene.name == scene.scene.name
    assert desc.left_out == scene.dae.left_out and desc.left_out
    assert desc.model == scene.dae.name != desc.name


def test_a_description_of_another_format_is_refused(pendulum):
    data = pendulum.description.to_dict()
    data["format"] = 99
    with pytest.raises(ValueError, match="format 99"):
        ModelDescription.from_dict(data)
    del data["format"]
    with pytest.raises(ValueError):
        ModelDescription.from_dict(data)


def test_options_of_a_compiled_model_cannot_be_changed():
    compiled = phc.compile_model(PENDULUM, certify=False)
    rtol = compiled.options["rtol"]
    with pytest.raises(TypeError):
        compiled.options["rtol"] = 0.5
    with pytest.raises(TypeError):
        compiled.description.options["nominal"]["pendulum.x"] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        compiled.description = dataclasses.replace(compiled.description, name="other")
    with pytest.raises(dataclasses.FrozenInstanceError):
        compiled.description.options = {}
    # the assembled system's options are read-only too, and survive a pickle as such
    with pytest.raises(TypeError):
        compiled.dae.options["rtol"] = 0.5
    copy = pickle.loads(pickle.dumps(compiled.dae))
    assert dict(copy.options) == dict(compiled.dae.options)
    with pytest.raises(TypeError):
        copy.options["rtol"] = 0.5
    result = phc.simulate(compiled, t_end=0.01, n_out=3)
    assert result.rtol == rtol


def test_caches_live_in_the_run_cache(pendulum):
    assert isinstance(pendulum.cache, RunCache)
    assert pendulum.cache.start_state is not None  # solved by the certificate, reused by simulate
    assert set(pendulum.timings) >= {"elaborate", "lower", "print", "load", "describe", "certify"}
    with pytest.raises(TypeError):
        pendulum.timings["load"] = 0.0  # a read-only view of cache.timings


def test_a_model_loaded_from_its_description_runs_bit_for_bit(pendulum):
    loaded = CompiledModel.from_description(ModelDescription.from_json(pendulum.description.to_json()),
                                            pendulum.source)
    assert loaded.dae is None and loaded.cache.start_state is None
    fresh = phc.compile_model(PENDULUM, certify=False)  # solves its start in simulate, as `loaded` does
    _same_run(phc.simulate(fresh, t_end=0.2, n_out=21), phc.simulate(loaded, t_end=0.2, n_out=21))
    # a parameter the initial value `pendulum.x: L` is written in needs the assembled system
    with pytest.raises(phc.SimulationSetupError, match="cannot evaluate it again"):
        phc.simulate(loaded, t_end=0.2, params={"L": 2.0})
    x = list(pendulum.module.VARIABLES).index("pendulum.x")
    assert phc.simulate(pendulum, t_end=0.01, n_out=2, params={"L": 2.0}).y[0, x] == 2.0
    # one it is not written in runs from the description
    _same_run(phc.simulate(fresh, t_end=0.2, n_out=21, params={"g": 5.0}),
              phc.simulate(loaded, t_end=0.2, n_out=21, params={"g": 5.0}))


def test_the_fast_path_loads_exactly_the_stored_description(tmp_path, monkeypatch):
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    monkeypatch.delenv(fastpath.ENV_SWITCH, raising=False)
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM.read_text(encoding="utf-8"), encoding="utf-8")
    args = build_parser().parse_args(["simulate", str(model), "--quiet"])
    assert fastpath.lookup(args, {}) is None
    with fastpath.recording(args) as recorder:  # what `phc simulate` does on a miss
        full = phc.compile_model(model)
    recorder.store(full, _written_options(str(model)))
    hit = fastpath.lookup(args, {})
    assert hit is not None and type(hit.compiled) is CompiledModel and hit.compiled.dae is None
    assert hit.compiled.description == full.description
    assert hit.compiled.source == full.source
    _same_run(phc.simulate(full, t_end=0.5, n_out=51), phc.simulate(hit.compiled, t_end=0.5, n_out=51))


def test_simulate_takes_only_a_compiled_model(pendulum):
    from types import SimpleNamespace

    imitation = SimpleNamespace(module=pendulum.module, dae=pendulum.dae, source=pendulum.source)
    with pytest.raises(TypeError, match="expects a compiled model"):
        phc.simulate(imitation, t_end=0.01)


def test_a_pickled_model_keeps_its_description_and_cache(pendulum):
    twin = pickle.loads(pickle.dumps(pendulum))
    assert type(twin) is CompiledModel and twin.module is not pendulum.module
    assert twin.description == pendulum.description
    assert twin.cache.timings == pendulum.cache.timings
    _same_run(phc.simulate(pendulum, t_end=0.1, n_out=11), phc.simulate(twin, t_end=0.1, n_out=11))


def test_equation_rows_are_labelled_when_read_and_share_their_places():
    """The equations of a description hold one place per distinct place (a mesh's rows share
    one) and read back as the Labelled items they were made from."""
    from phc.codegen.description import Labelled, LabelledRows, Place

    here, there = Place("m.yaml", 3, 5), Place("m.yaml", 9)
    items = [Labelled("beam.row[0]", "beam", here), Labelled("beam.row[1]", "beam", Place("m.yaml", 3, 5)),
             Labelled("energy.balance", "energy", None), Labelled("load.port", "load", there)]
    rows = LabelledRows(items)
    assert len(rows) == 4 and list(rows) == items and rows == tuple(items)
    assert rows[1] == items[1] and rows[-1] == items[-1] and rows[1:3] == tuple(items[1:3])
    assert len(rows._places) == 3  # equal places stored once: here, None, there
    assert rows != tuple(items[:3]) and rows != LabelledRows(items[:3])
    desc = phc.compile_model(PENDULUM, certify=False).description
    back = ModelDescription.from_json(desc.to_json())
    assert isinstance(back.equations, LabelledRows) and back.equations == desc.equations
    assert [eq.label for eq in back.equations] == list(desc.equations.labels)
