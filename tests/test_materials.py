import math
import warnings

import pytest

from mmwsim import MaterialRangeWarning, MmwsimError, get_material
from mmwsim.constants import VACUUM_PERMITTIVITY
from mmwsim.materials import ITU_MATERIALS, Material

F28 = 28e9


def test_concrete_at_28ghz_matches_p2040():
    m = get_material("concrete")
    assert m.relative_permittivity(F28) == pytest.approx(5.24)
    assert m.conductivity(F28) == pytest.approx(0.0462 * 28**0.7822, rel=1e-12)
    assert m.conductivity(F28) == pytest.approx(0.626, abs=5e-4)
    eps = m.complex_permittivity(F28)
    assert eps.imag == pytest.approx(-0.0462 * 28**0.7822 / (2 * math.pi * F28 * VACUUM_PERMITTIVITY))


@pytest.mark.parametrize(
    "name,a,b,c,d,fmin,fmax",
    [
        ("brick", 3.91, 0, 0.0238, 0.16, 1, 40),
        ("plasterboard", 2.73, 0, 0.0085, 0.9395, 1, 100),
        ("wood", 1.99, 0, 0.0047, 1.0718, 0.001, 100),
        ("glass", 6.31, 0, 0.0036, 1.3394, 0.1, 100),
        ("ceiling_board", 1.48, 0, 0.0011, 1.0750, 1, 100),
        ("chipboard", 2.58, 0, 0.0217, 0.78, 1, 100),
        ("plywood", 2.71, 0, 0.33, 0, 1, 40),
        ("marble", 7.074, 0, 0.0055, 0.9262, 1, 60),
        ("floorboard", 3.66, 0, 0.0044, 1.3515, 50, 100),
        ("metal", 1, 0, 1e7, 0, 1, 100),
        ("very_dry_ground", 3, 0, 0.00015, 2.52, 1, 10),
        ("medium_dry_ground", 15, -0.1, 0.035, 1.63, 1, 10),
        ("wet_ground", 30, -0.4, 0.15, 1.30, 1, 10),
    ],
)
def test_table3_rows(name, a, b, c, d, fmin, fmax):
    m = get_material(name)
    f = math.sqrt(fmin * fmax) * 1e9  # inside the stated range
    assert m.relative_permittivity(f) == pytest.approx(a * (f / 1e9) ** b)
    assert m.conductivity(f) == pytest.approx(c * (f / 1e9) ** d)
    assert m.band(f).f_min_ghz == fmin and m.band(f).f_max_ghz == fmax


def test_glass_second_band_above_220ghz():
    g = get_material("glass")
    assert g.relative_permittivity(300e9) == pytest.approx(5.79)
    assert g.conductivity(300e9) == pytest.approx(0.0004 * 300**1.658)


def test_every_table3_material_present():
    expected = {
        "vacuum", "concrete", "brick", "plasterboard", "wood", "glass", "ceiling_board", "chipboard",
        "plywood", "marble", "floorboard", "metal", "very_dry_ground", "medium_dry_ground", "wet_ground",
    }  # fmt: skip
    assert expected <= set(ITU_MATERIALS)


def test_out_of_range_warns_and_in_range_does_not():
    with pytest.warns(MaterialRangeWarning, match="wet_ground"):
        get_material("wet_ground").relative_permittivity(F28)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        get_material("concrete").relative_permittivity(F28)
        get_material("asphalt").relative_permittivity(F28)


def test_aliases_and_unknown():
    assert get_material("itu_concrete").name == "concrete"
    assert get_material("mat-itu_brick").name == "brick"
    assert get_material("Ceiling Board").name == "ceiling_board"
    with pytest.raises(MmwsimError, match="unknown material 'adamantium'"):
        get_material("adamantium")


def test_custom_material_and_thickness():
    m = Material.custom("mine", 4.0, 0.2, thickness=0.1)
    assert m.relative_permittivity(F28) == 4.0 and m.conductivity(5e9) == 0.2
    assert m.thickness == 0.1
    assert get_material("glass", thickness=0.01).thickness == 0.01
    assert get_material("concrete").thickness is None
    with pytest.raises(MmwsimError, match="permittivity"):
        Material.custom("bad", 0.5, 0.0)
    with pytest.raises(MmwsimError, match="conductivity"):
        Material.custom("bad", 2.0, -1.0)
    with pytest.raises(MmwsimError, match="thickness"):
        Material.custom("bad", 2.0, 0.0, thickness=0.0)
