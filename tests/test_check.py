"""popvol.check: canonical values for good input, one PopvolError line for anything else."""
import math

import numpy as np
import pytest

from popvol import check
from popvol.errors import PopvolError

HOSTILE = ["x", "", None, [[1, 2, 3]], [[0], [1, 2]], [1, "2", 3], ["a", "b", "c"], {"r": 1},
           1e308 * 10, math.nan, -math.inf, True, [True, 1, 1], np.array(["a", "b", "c"]),
           np.ones((2, 3)), object(), b"123", 10**400, [10**400, 0, 0], np.bool_(True)]


def one_line(fn, *args, **kw) -> str:
    with pytest.raises(PopvolError) as e:
        fn(*args, **kw)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("s.toml: "), msg
    return msg


@pytest.mark.parametrize("value", HOSTILE, ids=lambda v: type(v).__name__)
@pytest.mark.parametrize("fn,args", [
    (check.rgb, ()), (check.rgb, (0.0, 1.0)), (check.vector, ()), (check.vector, (True, True)),
    (check.integer, (0, 10)), (check.number, (0.0, 10.0)), (check.number, (-1.0, 1.0, True)),
    (check.choice, (("a", "b"),)), (check.table, ()),
])
def test_hostile_values_raise_popvol_error(fn, args, value):
    if fn is check.table and isinstance(value, dict):
        return
    msg = one_line(fn, value, "f.field", "s.toml", *args)
    assert "f.field" in msg


def test_rgb():
    np.testing.assert_array_equal(check.rgb(2, "a", "s"), [2.0, 2.0, 2.0])
    out = check.rgb([1, 0.5, np.float32(0.25)], "a", "s")
    assert out.dtype == np.float64 and out.shape == (3,) and out.tolist() == [1, 0.5, 0.25]
    np.testing.assert_array_equal(check.rgb(np.array([1, 2, 3]), "a", "s"), [1, 2, 3])
    np.testing.assert_array_equal(check.rgb((0, 1, 1), "a", "s", hi=1.0), [0, 1, 1])
    assert check.rgb(1e308, "a", "s").tolist() == [1e308] * 3
    msg = one_line(check.rgb, "x", "lights[0].irradiance", "s.toml")
    assert msg == "s.toml: lights[0].irradiance = 'x' must be 1 or 3 finite numbers >= 0"
    assert "in [0, 1]" in one_line(check.rgb, [0.5, 1.5, 0.5], "medium.albedo", "s.toml", 0.0, 1.0)
    for bad in ([1, 2], [1, 2, 3, 4], [], -1, [1, math.nan, 1], [1, 2, math.inf]):
        one_line(check.rgb, bad, "a", "s.toml")


def test_vector():
    v = check.vector([1, 2, 3], "v", "s")
    assert v.dtype == np.float64 and v.tolist() == [1, 2, 3]
    assert check.vector((0, 0, 0), "v", "s").tolist() == [0, 0, 0]
    assert check.vector(np.array([1e308, -1e308, 0]), "v", "s").tolist() == [1e308, -1e308, 0]
    for bad in (1.0, [1, 2], [1, 2, 3, 4], [1, math.nan, 0]):
        assert "3 finite numbers" in one_line(check.vector, bad, "camera.up", "s.toml")
    assert "not all 0" in one_line(check.vector, [0, 0, 0], "d", "s.toml", nonzero=True)
    assert "each > 0" in one_line(check.vector, [1, 0, 1], "d", "s.toml", positive=True)
    assert check.vector([1e-300, 1, 1], "d", "s", positive=True)[0] == 1e-300


def test_integer():
    assert check.integer(5, "n", "s", 0, 10) == 5 and type(check.integer(np.int64(5), "n", "s", 0, 10)) is int
    assert check.integer(10**20, "n", "s", 1, math.inf) == 10**20
    assert one_line(check.integer, 11, "method.spp", "s.toml", 1, 10) == \
        "s.toml: method.spp = 11 must be an integer in [1, 10]"
    assert ">= 1" in one_line(check.integer, 0, "camera.width", "s.toml", 1, math.inf)
    for bad in (5.0, 5.5, "5", True, False, np.bool_(False), np.float64(3), [5]):
        one_line(check.integer, bad, "n", "s.toml", 0, 10)


def test_number():
    assert check.number(1, "x", "s", 0, 1) == 1.0 and type(check.number(1, "x", "s", 0, 1)) is float
    assert check.number(np.float32(0.5), "x", "s", 0, 1) == 0.5
    assert check.number(np.array(0.5), "x", "s", 0, 1) == 0.5
    assert check.number(1e308, "x", "s", 0, math.inf) == 1e308
    assert one_line(check.number, 1.0, "medium.g", "s.toml", -1.0, 1.0, open_interval=True) == \
        "s.toml: medium.g = 1.0 must be a finite number in (-1, 1)"
    assert "in [0.001, 16]" in one_line(check.number, 17, "method.step", "s.toml", 1e-3, 16.0)
    assert "> 0" in one_line(check.number, 0, "medium.extent", "s.toml", 0.0, math.inf, open_interval=True)
    one_line(check.number, math.inf, "x", "s.toml", -math.inf, math.inf)
    for bad in ("1", [1], np.array([1.0]), True, None, math.nan):
        one_line(check.number, bad, "x", "s.toml", 0, 10)


def test_choice_table_known_keys():
    assert check.choice("a", "c", "s", ("a", "b")) == "a"
    assert check.choice("b", "c", "s", {"a": 1, "b": 2}) == "b"
    assert one_line(check.choice, "z", "experimental.solver", "s.toml", ("sweep", "jacobi")) == \
        "s.toml: experimental.solver = 'z' must be one of 'sweep', 'jacobi'"
    one_line(check.choice, ["a"], "c", "s.toml", {"a", "b"})      # unhashable, allowed a set
    d = {"x": 1}
    assert check.table(d, "t", "s") is d
    assert one_line(check.table, [1], "camera", "s.toml") == "s.toml: camera must be a table, got [1]"
    check.known_keys({"a": 1}, {"a", "b"}, "t.", "s")
    assert one_line(check.known_keys, {"a": 1, "c": 2}, ["a", "b"], "medium.", "s.toml") == \
        "s.toml: unknown key medium.c (known: a, b)"


def test_long_values_are_shortened_to_one_line():
    msg = one_line(check.rgb, "abc\n" * 100, "a", "s.toml")
    assert len(msg) < 200
    msg = one_line(check.rgb, np.ones((50, 50)), "a", "s.toml")
    assert "array of shape (50, 50)" in msg
