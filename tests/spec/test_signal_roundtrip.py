"""An input signal survives a dump and a re-validation unchanged and without pydantic's
serializer warnings: a scene rebuilds the simulation section that way (phc/frontend/scene.py), so a
table or a list of pieces classified as an expression on the way out would be a silently
different model on the way back in."""

import warnings

import pytest

from phc.spec.model import InputSpec, PieceSpec, TableSpec


def _signal(spec):
    return spec.effort if spec.effort is not None else spec.flow


CASES = [
    ({"effort": "sin(t)"}, lambda s: isinstance(s, str)),
    ({"effort": {"file": "force.csv", "column": "F"}}, lambda s: isinstance(s, TableSpec)),
    ({"flow": [{"until": 1.0, "value": "t"}, {"value": "1"}]}, lambda s: all(isinstance(p, PieceSpec) for p in s)),
    ({"effort": [{"file": "a.csv", "column": "x"}, "2*t"]},
     lambda s: isinstance(s[0], TableSpec) and isinstance(s[1], str)),
]


@pytest.mark.parametrize("given, kind", CASES)
def test_a_signal_dumps_and_validates_back_unchanged(given, kind):
    spec = InputSpec.model_validate(given)
    assert kind(_signal(spec))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dumped = spec.model_dump(exclude_unset=True)
    again = InputSpec.model_validate(dumped)
    assert again == spec and kind(_signal(again))
