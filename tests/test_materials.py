import math
import textwrap
import warnings

import numpy as np
import pytest

from mmwsim import MaterialRangeWarning, MmwsimError, get_material, load_scene
from mmwsim.constants import VACUUM_PERMITTIVITY
from mmwsim.materials import ITU_MATERIALS, Material, canonical_name
from scenes.layout import ground_mesh
from tests.helpers.scenes import write_scene_folder

F28 = 28e9

# ITU-R P.2040-3 Table 3, typed row by row from Sionna RT's radio_materials/itu.py and checked
# against DiffeRT's table (em/_material.py): name, then (a, b, c, d, f_min GHz, f_max GHz) per row,
# in the order of the table.
TABLE3 = {
    "vacuum": [(1.0, 0, 0.0, 0, 0.001, 100)],
    "concrete": [(5.24, 0, 0.0462, 0.7822, 1, 100), (5.17, 0, 0.0145, 1.09, 110, 330)],
    "brick": [(3.91, 0, 0.0238, 0.16, 1, 40), (4.15, 0, 0.0006, 1.5712, 110, 330)],
    "plasterboard": [
        (2.73, 0, 0.0085, 0.9395, 1, 100),
        (2.56, 0, 0.0001, 1.7799, 110, 330),
        (2.65, 0, 0.0002, 1.598, 100, 400),
    ],
    "wood": [
        (1.99, 0, 0.0047, 1.0718, 0.001, 100),
        (1.82, 0, 0.0040, 1.0761, 110, 330),
        (2.1183, 0, 0.0055, 1.1113, 100, 400),
    ],
    "glass": [
        (6.31, 0, 0.0036, 1.3394, 0.1, 100),
        (5.79, 0, 0.0004, 1.658, 220, 450),
        (6.5767, 0, 0.0012, 1.4697, 100, 400),
    ],
    "clear_acrylic": [(2.58, 0, 0.0001, 1.6524, 110, 330)],
    "ceiling_board": [
        (1.48, 0, 0.0011, 1.075, 1, 100),
        (1.52, 0, 0.0029, 1.029, 220, 450),
        (1.2567, 0, 0.00013, 1.454, 100, 400),
    ],
    "chipboard": [(2.58, 0, 0.0217, 0.78, 1, 100), (2.16, 0, 0.0023, 1.359, 100, 200)],
    "plywood": [
        (2.71, 0, 0.33, 0, 1, 40),
        (1.94, 0, 0.0067, 0.9982, 110, 330),
        (2.17, 0, 0.0063, 1.045, 100, 400),
    ],
    "marble": [
        (7.074, 0, 0.0055, 0.9262, 1, 60),
        (7.94, 0, 0.0001, 1.733, 110, 330),
        (8.62, 0, 0.0027, 1.15, 100, 400),
    ],
    "floorboard": [
        (3.66, 0, 0.0044, 1.3515, 50, 100),
        (5.27, 0, 2.22e-17, 7.3413, 220, 300),
        (5.27, 0, 0.0003, 2.0298, 300, 400),
        (5.27, 0, 49.8726, 0, 400, 450),
        (3.1575, 0, 0.001675, 1.32775, 100, 400),
    ],
    "vinyl_tile": [(3.62, 0, 0.0051, 0.8422, 1, 40)],
    "carpet_tile": [(2.08, 0, 0.0009, 0.82, 1, 40)],
    "asphalt_concrete": [(4.83, 0, 0.0108, 1.3969, 1, 40)],
    "metal": [(1.0, 0, 1e7, 0, 1, 100)],
    "very_dry_ground": [(3.0, 0, 0.00015, 2.52, 1, 10)],
    "medium_dry_ground": [(15.0, -0.1, 0.035, 1.63, 1, 10)],
    "wet_ground": [(30.0, -0.4, 0.15, 1.30, 1, 10)],
}

ROWS = [(name, i, row) for name, rows in TABLE3.items() for i, row in enumerate(rows)]


def test_every_table3_material_present():
    assert set(TABLE3) <= set(ITU_MATERIALS)
    # our measured road, under its own name, and the ideal conductor of the closed forms
    assert set(ITU_MATERIALS) - set(TABLE3) == {"asphalt", "perfect_conductor"}


def test_perfect_conductor_reflects_minus_one_plus_one():
    from mmwsim.tracer import Surface

    s = Surface.of([get_material("pec")], 28e9)
    r_te, r_tm = s.reflection(np.array([0.1]), 0.0107)
    assert r_te[0] == -1 and r_tm[0] == 1


@pytest.mark.parametrize("name", sorted(TABLE3))
def test_table3_bands_exact(name):
    bands = [(b.a, b.b, b.c, b.d, b.f_min_ghz, b.f_max_ghz) for b in ITU_MATERIALS[name].bands]
    assert bands == TABLE3[name]
    assert ITU_MATERIALS[name].source == "ITU-R P.2040-3 Table 3"


@pytest.mark.parametrize("name,i,row", ROWS, ids=[f"{n}-{i}" for n, i, _ in ROWS])
def test_table3_row_used_in_its_band(name, i, row):
    a, b, c, d, fmin, fmax = row
    earlier = TABLE3[name][:i]
    # a frequency inside this row and outside every earlier (preferred) row
    grid = [fmin * (fmax / fmin) ** (k / 200) for k in range(1, 200)]
    f_ghz = next(f for f in grid if not any(r[4] <= f <= r[5] for r in earlier))
    m = get_material(name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert m.relative_permittivity(f_ghz * 1e9) == pytest.approx(a * f_ghz**b, rel=1e-12)
        assert m.conductivity(f_ghz * 1e9) == pytest.approx(c * f_ghz**d, rel=1e-12)


def test_overlapping_bands_take_the_first_listed_row():
    # plasterboard: rows 110-330 and 100-400 GHz overlap; the earlier row is used inside both
    p = get_material("plasterboard")
    assert p.relative_permittivity(200e9) == 2.56
    assert p.relative_permittivity(105e9) == 2.65 and p.relative_permittivity(350e9) == 2.65
    assert get_material("glass").relative_permittivity(300e9) == 5.79


def test_concrete_at_28ghz_matches_p2040():
    m = get_material("concrete")
    assert m.relative_permittivity(F28) == pytest.approx(5.24)
    assert m.conductivity(F28) == pytest.approx(0.626, abs=5e-4)
    eps = m.complex_permittivity(F28)
    assert eps.imag == pytest.approx(-0.0462 * 28**0.7822 / (2 * math.pi * F28 * VACUUM_PERMITTIVITY))


def test_asphalt_concrete_is_p2040_not_our_asphalt():
    m = get_material("asphalt_concrete")
    assert m.name == "asphalt_concrete"
    assert m.relative_permittivity(F28) == 4.83
    assert m.conductivity(F28) == pytest.approx(0.0108 * 28**1.3969, rel=1e-12)
    assert m.conductivity(F28) == pytest.approx(1.1349, abs=1e-4)
    # the literature road surface keeps its own name and values
    assert get_material("asphalt").relative_permittivity(F28) == 3.18


@pytest.mark.parametrize(
    "spelling",
    [
        "asphalt_concrete",
        "itu_asphalt_concrete",
        "mat-itu_asphalt_concrete",
        "itu-asphalt-concrete",
        "Asphalt concrete",
        " ITU_ASPHALT_CONCRETE ",
    ],
)
def test_spellings_of_a_p2040_name(spelling):
    assert canonical_name(spelling) == "asphalt_concrete"
    assert get_material(spelling) is ITU_MATERIALS["asphalt_concrete"]


@pytest.mark.parametrize("name", sorted(TABLE3))
def test_every_name_loads_under_sionna_spellings(name):
    for spelling in (name, f"itu_{name}", f"mat-itu_{name}", name.replace("_", " ").title()):
        assert get_material(spelling).bands == ITU_MATERIALS[name].bands


def test_out_of_range_warns_and_in_range_does_not():
    with pytest.warns(MaterialRangeWarning, match="wet_ground"):
        get_material("wet_ground").relative_permittivity(F28)
    # between two bands: the nearest one on a log scale, with a warning
    with pytest.warns(MaterialRangeWarning, match="brick"):
        assert get_material("brick").relative_permittivity(60e9) == 3.91
    with pytest.warns(MaterialRangeWarning, match="brick"):
        assert get_material("brick").relative_permittivity(100e9) == 4.15
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        get_material("concrete").relative_permittivity(F28)
        get_material("asphalt").relative_permittivity(F28)
        get_material("asphalt_concrete").relative_permittivity(F28)


def test_aliases_and_unknown():
    assert get_material("itu_concrete").name == "concrete"
    assert get_material("mat-itu_brick").name == "brick"
    assert get_material("Ceiling Board").name == "ceiling_board"
    assert canonical_name("adamantium") is None
    with pytest.raises(MmwsimError, match="unknown material 'adamantium'"):
        get_material("adamantium")
    for f in (float("nan"), -1.0, 0.0, float("inf")):
        with pytest.raises(MmwsimError, match="frequency must be a positive, finite number"):
            get_material("concrete").complex_permittivity(f)


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


# ---------------------------------------------------------------- diffuse scattering parameters


def test_scattering_defaults_and_copy():
    c = get_material("concrete")
    assert (c.scattering_coefficient, c.xpd_coefficient, c.scattering_pattern, c.alpha_r) == (
        0.0,
        0.0,
        "lambertian",
        4,
    )
    r = c.with_scattering(S=0.3, xpd=0.1, pattern="directive", alpha_r=2)
    assert (r.scattering_coefficient, r.xpd_coefficient, r.scattering_pattern, r.alpha_r) == (
        0.3,
        0.1,
        "directive",
        2,
    )
    assert r.bands == c.bands and c.scattering_coefficient == 0.0  # a copy, the original unchanged
    assert r.with_scattering(xpd=0.2).scattering_coefficient == 0.3  # None keeps
    assert r.with_thickness(0.2).scattering_coefficient == 0.3
    assert repr(r) == repr(c.with_scattering(0.3, 0.1, "directive", 2))  # deterministic
    assert repr(r) != repr(c)
    m = Material.custom("mine", 4.0, 0.2, scattering_coefficient=0.5, alpha_r=3)
    assert m.scattering_coefficient == 0.5 and m.alpha_r == 3


@pytest.mark.parametrize(
    "kwargs,key",
    [
        ({"S": 1.5}, "scattering_coefficient"),
        ({"S": -0.1}, "scattering_coefficient"),
        ({"S": float("nan")}, "scattering_coefficient"),
        ({"xpd": float("inf")}, "xpd_coefficient"),
        ({"xpd": 2.0}, "xpd_coefficient"),
        ({"pattern": "specular"}, "scattering_pattern"),
        ({"alpha_r": 0}, "alpha_r"),
        ({"alpha_r": 2.5}, "alpha_r"),
        ({"alpha_r": True}, "alpha_r"),
    ],
)
def test_scattering_bad_values(kwargs, key):
    with pytest.raises(MmwsimError, match=f"^material 'brick': {key} must") as e:
        get_material("brick").with_scattering(**kwargs)
    assert "\n" not in str(e.value)


def _scene_with_materials(tmp_path, materials: str, ground: str = "asphalt", block: str = "concrete"):
    path = write_scene_folder(tmp_path)
    text = path.read_text().replace(
        "[materials.tinted]\npermittivity = 6.0\nconductivity = 0.1\n", textwrap.dedent(materials)
    )
    text = text.replace('material = "asphalt"', f'material = "{ground}"')
    text = text.replace('material = "concrete"', f'material = "{block}"')
    path.write_text(text)
    return path


def test_toml_overrides_builtin_and_defines_custom(tmp_path):
    path = _scene_with_materials(
        tmp_path,
        """
        [materials.itu_concrete]
        scattering_coefficient = 0.4
        xpd_coefficient = 0.2
        scattering_pattern = "directive"
        alpha_r = 3
        thickness = 0.25

        [materials.asphalt_concrete]
        scattering_coefficient = 0.1
        """,
        ground="mat-itu_asphalt_concrete",
    )
    s = load_scene(path)
    ground, block = s.objects[0].material, s.objects[1].material
    assert ground.name == "asphalt_concrete" and ground.relative_permittivity(F28) == 4.83
    assert ground.scattering_coefficient == 0.1 and ground.scattering_pattern == "lambertian"
    assert block.name == "concrete" and block.bands == ITU_MATERIALS["concrete"].bands
    assert (block.scattering_coefficient, block.xpd_coefficient, block.scattering_pattern, block.alpha_r) == (
        0.4,
        0.2,
        "directive",
        3,
    )
    assert block.thickness == 0.3  # the object's own thickness wins over the entry's
    rough = load_scene(_scene_with_materials(tmp_path, ROUGH, block="rough")).objects[1].material
    assert rough.name == "rough" and rough.relative_permittivity(F28) == 6.0
    assert rough.scattering_coefficient == 0.6


ROUGH = """
[materials.rough]
permittivity = 6.0
conductivity = 0.1
scattering_coefficient = 0.6
"""


@pytest.mark.parametrize(
    "materials,match",
    [
        (
            "[materials.concrete]\nscattering_coefficient = 1.5\n",
            "materials.concrete: .*scattering_coefficient",
        ),
        ("[materials.concrete]\nxpd_coefficient = nan\n", "xpd_coefficient"),
        ("[materials.concrete]\nscattering_pattern = 'spiky'\n", "scattering_pattern"),
        ("[materials.concrete]\nalpha_r = 0\n", "alpha_r"),
        ("[materials.concrete]\nalpha_r = 2.5\n", "alpha_r"),
        ("[materials.concrete]\nroughness = 0.1\n", "unknown key 'materials.concrete.roughness'"),
        ("[materials.unobtainium]\nscattering_coefficient = 0.1\n", "not a built-in material"),
        ("[materials.half]\npermittivity = 3.0\n", "both 'permittivity' and 'conductivity'"),
    ],
)
def test_toml_bad_material_entries(tmp_path, materials, match):
    path = _scene_with_materials(tmp_path, materials)
    with pytest.raises(MmwsimError, match=match) as e:
        load_scene(path)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


XML = """\
<scene version="2.1.0">
  <bsdf type="itu-radio-material" id="mat-itu_asphalt_concrete">
    <string name="type" value="asphalt_concrete"/>
    <float name="scattering_coefficient" value="{s}"/>
    <float name="xpd_coefficient" value="0.25"/>
  </bsdf>
  <bsdf type="radio-material" id="rough">
    <float name="relative_permittivity" value="4.5"/>
    <float name="conductivity" value="0.02"/>
    <float name="scattering_coefficient" value="0.5"/>
    <string name="scattering_pattern" value="directive"/>
    <integer name="alpha_r" value="{alpha}"/>
  </bsdf>
  <shape type="ply" id="mesh-ground">
    <string name="filename" value="ground.ply"/>
    <ref id="mat-itu_asphalt_concrete" name="bsdf"/>
  </shape>
  <shape type="ply" id="mesh-kiosk">
    <string name="filename" value="kiosk.ply"/>
    <ref id="rough" name="bsdf"/>
  </shape>
</scene>
"""


def _xml_scene(tmp_path, s="0.3", alpha="6"):
    import trimesh

    ground_mesh(0, 0, 50, 50).export(tmp_path / "ground.ply")
    trimesh.creation.box((2, 2, 3), trimesh.transformations.translation_matrix((20, 10, 1.5))).export(
        tmp_path / "kiosk.ply"
    )
    path = tmp_path / "scene.xml"
    path.write_text(XML.format(s=s, alpha=alpha))
    return path


def test_mitsuba_scattering_properties(tmp_path):
    s = load_scene(_xml_scene(tmp_path))
    by_name = {o.name: o.material for o in s.objects}
    g, k = by_name["ground"], by_name["kiosk"]
    assert g.name == "asphalt_concrete" and g.relative_permittivity(F28) == 4.83
    assert (
        g.scattering_coefficient == 0.3 and g.xpd_coefficient == 0.25 and g.scattering_pattern == "lambertian"
    )
    assert k.scattering_coefficient == 0.5 and k.scattering_pattern == "directive" and k.alpha_r == 6


@pytest.mark.parametrize(
    "s,alpha,match",
    [
        ("1.2", "4", "scattering_coefficient must be in"),
        ("-0.5", "4", "scattering_coefficient must be in"),
        ("nan", "4", "scattering_coefficient=.nan. is not a finite number"),
        ("lots", "4", "scattering_coefficient='lots' is not a number"),
        ("0.3", "0", "alpha_r must be an integer >= 1"),
        ("0.3", "2.5", "alpha_r='2.5' is not an integer"),
    ],
)
def test_mitsuba_bad_scattering_values(tmp_path, s, alpha, match):
    path = _xml_scene(tmp_path, s, alpha)
    with pytest.raises(MmwsimError, match=match) as e:
        load_scene(path)
    assert "\n" not in str(e.value) and str(path) in str(e.value)
