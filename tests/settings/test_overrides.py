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
