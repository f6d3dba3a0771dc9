"""The one check of users' TOML tables (contracts/toml_tables.py): every refusal names
the field, the range and the unit; what is taken comes back as a float."""

from __future__ import annotations

import math

import pytest

from contracts.toml_tables import array_of_tables, check_fields, number, subtable


class FileError(ValueError):
    pass


@pytest.mark.parametrize("value, kwargs, message", [
    (True, {}, "x must be a finite number, got True"),
    ("1", {}, "x must be a finite number, got '1'"),
    (math.nan, {"low": 0.0}, "x must be a finite number >= 0, got nan"),
    (math.inf, {"low": 0.0, "high": 5.0, "unit": "s"}, "x must be a number in [0, 5] s, got inf"),
    (0.0, {"low": 0.0, "high": 5.0, "low_open": True}, "x must be a number in (0, 5], got 0.0"),
    (6, {"low": 0.0, "high": 5.0, "unit": "Hz"}, "x must be a number in [0, 5] Hz, got 6"),
    (-1, {"high": 0.0}, None),
    (1, {"high": 0.0}, "x must be a finite number <= 0, got 1"),
    (math.inf, {"low": 0.0, "allow_inf": True, "high": 9.0}, "x must be a number in [0, 9]"),
])
def test_numbers_are_refused_saying_the_range_and_unit(value, kwargs, message):
    if message is None:
        assert number(value, "x", **kwargs) == -1.0
        return
    with pytest.raises(ValueError) as info:
        number(value, "x", **kwargs)
    assert str(info.value).startswith(message), str(info.value)


def test_a_number_taken_is_a_float_and_infinity_only_where_a_window_never_ends():
    assert number(3, "x", 0.0, 5.0) == 3.0 and isinstance(number(3, "x", 0.0, 5.0), float)
    assert number(math.inf, "end_s", 0.0, math.inf, allow_inf=True) == math.inf
    with pytest.raises(ValueError, match="end_s must be a finite number >= 0"):
        number(math.inf, "end_s", 0.0, math.inf)


def test_the_reader_s_own_error_type_is_raised():
    with pytest.raises(FileError, match="airframe: mass_kg"):
        number(-1.0, "airframe: mass_kg", 0.001, 1000.0, error=FileError)
    with pytest.raises(FileError, match="unknown field"):
        check_fields({"mas": 1}, {"mass_kg"}, "airframe", FileError)


def test_unknown_fields_are_named_with_the_known_ones():
    check_fields({"a": 1}, ("a", "b"), "t")
    with pytest.raises(ValueError) as info:
        check_fields({"a": 1, "zz": 2, "c": 3}, ("a", "b"), "plant")
    assert str(info.value) == "plant: unknown field(s) c, zz; known: a, b"


def test_subtables_and_arrays_of_tables():
    assert subtable({}, "plant", "[plant]") == {}
    with pytest.raises(ValueError, match=r"\[plant\] must be a table"):
        subtable({"plant": 3}, "plant", "[plant]")
    assert array_of_tables({}, "event", "expect.event", ("kind",)) == []
    got = array_of_tables({"event": [{"kind": 1}, {}]}, "event", "expect.event", ("kind",))
    assert got == [("expect.event 0", {"kind": 1}), ("expect.event 1", {})]
    for data, message in (({"event": {"kind": 1}}, r"must be an array of tables \(\[\[event\]\]\)"),
                          ({"event": [{"kind": 1}, 2]}, "expect.event 1 must be a table"),
                          ({"event": [{"when": 1}]}, r"expect.event 0: unknown field\(s\) when")):
        with pytest.raises(ValueError, match=message):
            array_of_tables(data, "event", "expect.event", ("kind",))
