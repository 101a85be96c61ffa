"""The small TOML writer: whatever it writes, tomllib reads back unchanged."""

import math
import tomllib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trajgen.keyframes import BUILTIN_EXAMPLE
from trajgen.toml_writer import dumps

keys = st.text(min_size=1, max_size=8)
scalars = (
    st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**63 - 1)
    | st.floats(allow_nan=False)
    | st.text(max_size=12)
)
values = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(keys, inner, max_size=3),
    max_leaves=12,
)
documents = st.dictionaries(
    keys,
    values | st.lists(st.dictionaries(keys, values, max_size=3), min_size=1, max_size=3),
    max_size=5,
)


@settings(derandomize=True, max_examples=200, deadline=None)
@given(documents)
def test_round_trip(document):
    assert tomllib.loads(dumps(document)) == document


def test_keyframe_file_round_trips():
    document = tomllib.loads(BUILTIN_EXAMPLE.read_text())
    text = dumps(document)
    assert tomllib.loads(text) == document
    assert "[gimbal]" in text and text.count("[[keyframes]]") == len(document["keyframes"])


def test_special_values():
    document = {"a b": 'tab\there "quoted" \\ \x01', "x": [math.inf, -math.inf], "n": math.nan}
    back = tomllib.loads(dumps(document))
    assert back["a b"] == document["a b"] and back["x"] == document["x"]
    assert math.isnan(back["n"])


def test_unsupported_type_raises():
    with pytest.raises(TypeError, match="Cannot write"):
        dumps({"when": object()})
    with pytest.raises(TypeError, match="keys are strings"):
        dumps({1: 2})
    with pytest.raises(TypeError, match="Expected `document` to be a dict"):
        dumps([1])
