"""The light interface: every registered kind loads from its TOML table, round-trips through
table(), scales its power, keys its solution by what the walk depends on, and runs through the
one pipeline with a balanced energy budget."""
import numpy as np
import pytest

from popvol import PopvolError, scene_from_dict
from popvol.lights import LIGHTS, Light
from popvol.pipeline import solve, solve_light
from popvol.renderer import render
from popvol.medium import Medium
from popvol.method import Method

TABLES = {"directional": {"type": "directional", "direction": [0.2, -1.0, 0.3], "irradiance": [1.0, 2.0, 3.0]},
          "point": {"type": "point", "position": [0.5, 0.9, 0.4], "intensity": [1.0, 2.0, 3.0]}}


def blob(n=12):
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    rho = np.exp(-((X - 0.5) ** 2 + (Y - 0.5) ** 2 + (Z - 0.5) ** 2) / 0.05).astype(np.float32)
    return Medium(rho, 1.0 / n, np.full(3, 0.5 / n), scale=6.0, albedo=0.95, g=0.6)


def test_every_kind_has_a_table_to_test():
    assert set(LIGHTS) == set(TABLES)


@pytest.mark.parametrize("kind", sorted(TABLES))
def test_table_round_trip_scale_and_key(kind):
    cls = LIGHTS[kind]
    assert issubclass(cls, Light) and cls.type == kind and set(TABLES[kind]) <= cls.keys
    light = cls.from_table(TABLES[kind], "lights[0]", "t.toml")
    again = cls.from_table(light.table(), "lights[0]", "t.toml")
    assert again.key() == light.key()
    np.testing.assert_array_equal(again.power, light.power)
    np.testing.assert_allclose(light.power, [1.0, 2.0, 3.0])
    brighter = light.scaled(2.0)
    np.testing.assert_allclose(brighter.power, 2.0 * light.power)
    assert brighter.key() == light.key()          # fields are per unit power: same solution
    assert light.mitsuba()["type"] == kind
    assert isinstance(light.digest(), bytes) and light.digest() != brighter.digest()


@pytest.mark.parametrize("kind", sorted(TABLES))
def test_missing_required_field_is_one_line_error(kind):
    required = {"directional": "direction", "point": "position"}[kind]
    table = {k: v for k, v in TABLES[kind].items() if k != required}
    with pytest.raises(PopvolError, match=rf"t.toml: lights\[0\]\.{required} is required"):
        LIGHTS[kind].from_table(table, "lights[0]", "t.toml")


@pytest.mark.parametrize("kind", sorted(TABLES))
@pytest.mark.parametrize("isotropic", ["walk", "diffusion"])
@pytest.mark.parametrize("solver", ["ordinates", "sweep"])
def test_each_kind_runs_the_one_pipeline_and_balances(kind, isotropic, solver):
    """Energy balance of supplement Sec. 1.2 (docs/METHOD.md Eq. 16), the diffusion stage
    included: what was injected is escaped, absorbed or still in flight. The diffusion stage
    runs where it is asked for, but for a sun walked with six ordinates (every order walked)."""
    med = blob()
    light = LIGHTS[kind].from_table(TABLES[kind], "lights[0]", "t.toml")
    ds = solve_light(med, light, Method(resolution=12, isotropic=isotropic, solver=solver, tolerance=1e-5))
    b = ds.result.budget
    assert b.injected > 0 and b.absorbed > 0
    assert abs(b.balance_error) < 1e-4
    walks_every_order = kind == "directional" and solver == "ordinates"
    assert (ds.result.diffusion is not None) == (isotropic == "diffusion" and not walks_every_order)
    assert ds.stats()["type"] == kind


def test_solution_counts_every_array_and_relights():
    scene = scene_from_dict({"medium": {"type": "procedural", "resolution": 16},
                             "lights": [TABLES["directional"], TABLES["point"]],
                             "method": {"resolution": 12}})
    sol = solve(scene)
    arrays = (sol.phi, sol.phia, sol.direct, sol.phid, sol.flux, sol.points.fields)
    assert sol.nbytes == sum(a.nbytes for a in arrays)
    assert sol.points.fields.size > 3                # the point light's block is counted
    relit = sol.relit([l.scaled(3.0) for l in scene.lights])
    np.testing.assert_allclose(relit.irradiance, 3.0 * sol.irradiance)
    assert relit.phi is sol.phi
    # what a render keeps with the solution (its gather state) is counted, once
    render(scene, sol)
    (_key, _held, state), = sol.cache.values()
    lobes = state[5]
    assert lobes.nbytes > 0 and relit.nbytes == sol.nbytes >= sum(a.nbytes for a in arrays) + lobes.nbytes
