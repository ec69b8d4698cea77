"""A bounded fuzzer over the model and scene loaders (the ``phc validate`` path).

Every input must end in success or in located one-line diagnostics — never another
exception, never a hang (see :mod:`fuzzlib` for the oracle and the strategies). Two kinds
of input:

* random documents, for model files and scene files: three in four built the way a user
  writes them (:func:`fuzzlib.models`, :func:`fuzzlib.scenes`: components of every library
  kind with their ports and states, connections, inputs, outputs, scenes of the shipped
  models; a per-document noise level makes values wrong), one in four shaped only by the
  schema (:func:`fuzzlib.documents`: the keys and value types of the spec classes, values
  from anywhere now and then);
* mutations of every shipped model and scene (:func:`fuzzlib.mutations`: deleted keys,
  swapped types, numbers made strings, negative or huge numbers, renamed references,
  duplicated components, aliases, truncated or edited text).

One input in eight that validates is also compiled; one in eight goes through the command
line (`phc.cli.main(["validate", FILE])`) instead of the API.

The default run is derandomized (the same examples on every CI run) and bounded:
``FUZZ_EXAMPLES`` examples per test (see below), about 30 s on a 2-core machine. The
``slow`` variants draw fresh random examples, many more of them::

    python -m pytest tests/fuzz -q                     # the bounded, reproducible run
    python -m pytest tests/fuzz -q -m slow             # random seed, 20x the examples
    PHC_FUZZ_EXAMPLES=2000 python -m pytest tests/fuzz -q -m slow

A failure prints the input; keep it under ``tests/fuzz/found/`` (see
``test_found_corpus.py``) and fix the loader.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import fuzzlib

FUZZ_EXAMPLES = {"documents": 150, "scenes": 60, "mutations": 25}
"""Examples per test in the default run (mutations: per shipped file)."""
SLOW_FACTOR = 20

_COMMON = dict(deadline=None,  # the per-input limit is fuzzlib.TIME_LIMIT of CPU time (time_limits.py), robust to a loaded machine
               database=None,
               suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                      HealthCheck.function_scoped_fixture, HealthCheck.filter_too_much])


def _settings(kind: str, slow: bool):
    n = FUZZ_EXAMPLES[kind]
    if slow:
        n = int(os.environ.get("PHC_FUZZ_EXAMPLES", n * SLOW_FACTOR))
        return settings(max_examples=n, derandomize=False, **_COMMON)
    return settings(max_examples=n, derandomize=True, **_COMMON)


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> Path:
    return fuzzlib.workspace(tmp_path_factory.mktemp("fuzz"))


def _run(path: Path, text: str, how: int) -> None:
    """`how` (drawn 0–7): 0 validate and compile, 1 the command line's `main`, else validate."""
    path.write_text(text, encoding="utf-8")
    root = path.parent if path.parent.name == "models" else path.parent.parent
    files = {str(p) for p in root.rglob("*") if p.is_file()}
    try:
        event(fuzzlib.check_input(path, files, compile=how == 0, cli=how == 1))  # --hypothesis-show-statistics
    except BaseException:
        print(f"--- failing input ({path.name}) ---\n{text}\n--- end ---")
        raise


MODELS = fuzzlib.models()
SCENES = fuzzlib.scenes()
DOCUMENTS = fuzzlib.documents()


def _documents(models: Path, data) -> None:
    if data.draw(st.integers(0, 3), label="grammar?"):
        doc = data.draw(MODELS, label="model")
    else:  # anything shaped like the model schema
        doc = data.draw(DOCUMENTS, label="document")
    text = fuzzlib.dump(doc, data.draw(st.sampled_from([None, False, True]), label="flow style"))
    _run(models / "fuzz_doc.yaml", text, data.draw(st.integers(0, 7), label="how"))


def _scenes(models: Path, data) -> None:
    if data.draw(st.integers(0, 3), label="grammar?"):
        doc = data.draw(SCENES, label="scene")
    else:  # anything shaped like the scene schema
        doc = data.draw(fuzzlib.scene_documents, label="scene")
        if data.draw(st.booleans(), label="real model?"):
            doc["model"] = data.draw(st.sampled_from([f"../{p.name}" for p in sorted(models.glob("*.yaml"))]))
    text = fuzzlib.dump(doc, data.draw(st.sampled_from([None, False]), label="flow style"))
    _run(models / "scenes" / "fuzz_scene.yaml", text, data.draw(st.integers(0, 7), label="how"))


def _mutations(models: Path, source: Path, data) -> None:
    text = data.draw(fuzzlib.mutations(source), label="mutated")
    target = models / source.relative_to(fuzzlib.MODELS).with_name("fuzz_" + source.name)
    _run(target, text, data.draw(st.integers(0, 7), label="how"))


SOURCES = [pytest.param(p, id=str(p.relative_to(fuzzlib.MODELS))) for p in fuzzlib.SHIPPED]


# -- the default (bounded, derandomized) run ----------------------------------------

@_settings("documents", slow=False)
@given(data=st.data())
def test_random_model_documents(models, data):
    _documents(models, data)


@_settings("scenes", slow=False)
@given(data=st.data())
def test_random_scene_documents(models, data):
    _scenes(models, data)


@pytest.mark.parametrize("source", SOURCES)
@_settings("mutations", slow=False)
@given(data=st.data())
def test_mutations_of_shipped_files(models, source, data):
    _mutations(models, source, data)


# -- the slow runs: a random seed and many more examples ----------------------------

@pytest.mark.slow
@_settings("documents", slow=True)
@given(data=st.data())
def test_random_model_documents_slow(models, data):
    _documents(models, data)


@pytest.mark.slow
@_settings("scenes", slow=True)
@given(data=st.data())
def test_random_scene_documents_slow(models, data):
    _scenes(models, data)


@pytest.mark.slow
@pytest.mark.parametrize("source", SOURCES)
@_settings("mutations", slow=True)
@given(data=st.data())
def test_mutations_of_shipped_files_slow(models, source, data):
    _mutations(models, source, data)
