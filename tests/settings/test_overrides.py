"""Values written as ``key=value`` overrides (the Python API's changes) read back as given."""

from __future__ import annotations

import pytest

from settings import ConfigError
from settings.overrides import format_value, parse_value


@pytest.mark.parametrize(
    "value",
    [1, -2.5, True, 'a "quoted" name', [1, "a", 2.0], {"a": {"b": [1.5, False]}, "c d": "e"}],
)
def test_a_value_formatted_for_an_override_parses_back_to_itself(value):
    assert parse_value(format_value(value)) == value


def test_a_value_that_cannot_be_a_setting_is_named():
    with pytest.raises(ConfigError, match="object"):
        format_value(object())


def test_numpy_numbers_are_numbers_not_their_repr():
    # numpy 2's repr of a float64 is "np.float64(2.0)": it reached a scheme as that string
    np = pytest.importorskip("numpy")
    for value, plain in [(np.float64(2.0), 2.0), (np.int64(3), 3), (np.float32(0.5), 0.5)]:
        back = parse_value(format_value(value))
        assert back == plain and type(back) is type(plain)
    assert parse_value(format_value({"gain": np.linspace(1.0, 3.0, 3)[1]})) == {"gain": 2.0}
