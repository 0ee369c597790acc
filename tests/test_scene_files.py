"""Scene files: TOML, bare meshes in every format, Mitsuba XML, and every bad-input case."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh

from mmwsim import MmwsimError, load_scene
from scenes.layout import ground_mesh
from tests.helpers.scenes import two_buildings, write_scene_folder


def test_toml_scene_loads(scene_folder):
    s = load_scene(scene_folder)
    assert s.name == "tiny"
    assert [o.name for o in s.objects] == ["ground", "block_0", "block_1"]
    assert [o.kind for o in s.objects] == ["ground", "building", "building"]
    assert s.objects[0].material.name == "asphalt"
    assert s.objects[1].material.name == "concrete" and s.objects[1].material.thickness == 0.3
    assert s.transmitter.position == (5.0, 5.0, 10.0)
    assert s.receivers.shape == (51, 51) and s.receivers.spacing == 2.0
    assert len(s.footprints) == 2
    # the folder itself resolves to its scene file
    assert load_scene(scene_folder.parent).name == "tiny"


def test_toml_user_material(tmp_path):
    path = write_scene_folder(tmp_path)
    text = path.read_text().replace('material = "concrete"', 'material = "tinted"')
    path.write_text(text)
    s = load_scene(path)
    m = s.objects[1].material
    assert m.name == "tinted" and m.relative_permittivity(28e9) == 6.0 and m.conductivity(28e9) == 0.1
    assert m.thickness == 0.3


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".glb", ".stl"])
def test_bare_mesh_formats(tmp_path, suffix):
    mesh = trimesh.util.concatenate([two_buildings(), ground_mesh(0, 0, 100, 100)])
    path = tmp_path / f"city{suffix}"
    mesh.export(path)
    s = load_scene(path)
    np.testing.assert_allclose(s.extent, [[0, 0, 0], [100, 100, 25]], atol=1e-5)
    assert s.n_triangles == 26
    assert s.transmitter is None
    # coordinates kept as given: the two buildings are where they were written
    assert s.outdoors(np.array([[20, 15, 1.5], [45, 45, 1.5], [35, 25, 1.5]])).tolist() == [
        False,
        False,
        True,
    ]


def test_glb_named_parts(tmp_path):
    sc = trimesh.Scene()
    sc.add_geometry(ground_mesh(0, 0, 100, 100), geom_name="ground", node_name="ground")
    sc.add_geometry(two_buildings(), geom_name="towers", node_name="towers")
    sc.export(tmp_path / "city.glb")
    s = load_scene(tmp_path / "city.glb", transmitter=(5, 5, 10))
    kinds = {o.name: o.kind for o in s.objects}
    assert kinds == {"ground": "ground", "towers": "building"}
    assert s.transmitter.position == (5, 5, 10)


MITSUBA = """\
<scene version="2.1.0">
  <bsdf type="itu-radio-material" id="mat-itu_concrete">
    <string name="type" value="concrete"/>
    <float name="thickness" value="0.2"/>
  </bsdf>
  <bsdf type="twosided" id="mat-glass">
    <bsdf type="itu-radio-material">
      <string name="type" value="glass"/>
      <float name="thickness" value="0.01"/>
    </bsdf>
  </bsdf>
  <bsdf type="radio-material" id="custom">
    <float name="relative_permittivity" value="4.5"/>
    <float name="conductivity" value="0.02"/>
  </bsdf>
  <bsdf type="diffuse" id="mat-itu_medium_dry_ground"/>
  <shape type="ply" id="mesh-Ground">
    <string name="filename" value="meshes/ground.ply"/>
    <ref id="mat-itu_medium_dry_ground" name="bsdf"/>
  </shape>
  <shape type="ply" id="mesh-towers">
    <string name="filename" value="meshes/towers.ply"/>
    <boolean name="face_normals" value="true"/>
    <ref id="mat-itu_concrete" name="bsdf"/>
  </shape>
  <shape type="obj" id="mesh-glass_box">
    <string name="filename" value="meshes/box.obj"/>
    <transform name="to_world"><translate x="70" y="70" z="0"/></transform>
    <ref id="mat-glass" name="bsdf"/>
  </shape>
  <shape type="ply" id="mesh-kiosk">
    <string name="filename" value="meshes/kiosk.ply"/>
    <ref id="custom"/>
  </shape>
</scene>
"""


def write_mitsuba(folder: Path, text: str = MITSUBA) -> Path:
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    ground_mesh(0, 0, 100, 100).export(folder / "meshes" / "ground.ply")
    two_buildings().export(folder / "meshes" / "towers.ply")
    trimesh.creation.box((4, 4, 4), trimesh.transformations.translation_matrix((0, 0, 2))).export(
        folder / "meshes" / "box.obj"
    )
    trimesh.creation.box((2, 2, 3), trimesh.transformations.translation_matrix((80, 10, 1.5))).export(
        folder / "meshes" / "kiosk.ply"
    )
    path = folder / "scene.xml"
    path.write_text(text)
    return path


def test_mitsuba_scene(tmp_path):
    s = load_scene(write_mitsuba(tmp_path))
    by_name = {o.name: o for o in s.objects}
    assert set(by_name) == {"Ground", "towers", "glass_box", "kiosk"}
    assert by_name["Ground"].kind == "ground"
    assert by_name["Ground"].material.name == "medium_dry_ground"
    assert by_name["towers"].material.name == "concrete" and by_name["towers"].material.thickness == 0.2
    assert by_name["glass_box"].material.name == "glass" and by_name["glass_box"].material.thickness == 0.01
    np.testing.assert_allclose(by_name["glass_box"].mesh.bounds, [[68, 68, 0], [72, 72, 4]])
    assert by_name["kiosk"].material.relative_permittivity(28e9) == 4.5
    assert not s.outdoors(np.array([[70.0, 70.0, 1.0]]))[0]


# ---------------------------------------------------------------- bad input


def _replace(path: Path, old: str, new: str) -> Path:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.parametrize(
    "old,new,message",
    [
        ('mesh = "meshes/ground.ply"', 'mesh = "meshes/nothere.ply"', "mesh file not found"),
        ('material = "concrete"', 'material = "unobtainium"', "unknown material 'unobtainium'"),
        ('kind = "ground"', 'kind = "ground"\ncolour = "red"', "unknown key 'objects.0.colour'"),
        ("spacing = 2.0", 'spacing = "two"', "key 'receivers.spacing'"),
        ("spacing = 2.0", "spacing = -1.0", "key 'receivers.spacing'"),
        ("position = [5.0, 5.0, 10.0]", "position = [20.0, 15.0, 5.0]", "inside a building"),
        ("position = [5.0, 5.0, 10.0]", "position = [500.0, 5.0, 10.0]", "outside the scene"),
        ("position = [5.0, 5.0, 10.0]", "position = [5.0, 5.0]", "key 'transmitter.position'"),
        ('mesh = "meshes/ground.ply"', 'mesh = "../escape.ply"', "leaves the scene folder"),
        ('mesh = "meshes/ground.ply"', 'mesh = "/etc/passwd"', "must be relative"),
        ('name = "tiny"', 'name = "tiny"\nbogus = 1', "unknown key 'bogus'"),
        ("[transmitter]", "[transmitter\n", "malformed TOML"),
    ],
)
def test_toml_errors(tmp_path, old, new, message):
    path = _replace(write_scene_folder(tmp_path / "s"), old, new)
    (tmp_path / "escape.ply").write_bytes((tmp_path / "s" / "meshes" / "ground.ply").read_bytes())
    with pytest.raises(MmwsimError, match=message) as e:
        load_scene(path)
    assert "\n" not in str(e.value)
    assert str(path) in str(e.value)


def test_toml_no_objects(tmp_path):
    path = tmp_path / "empty.toml"
    path.write_text('name = "x"\nobjects = []\n')
    with pytest.raises(MmwsimError, match="objects"):
        load_scene(path)


def test_empty_mesh_file_is_not_a_mesh(tmp_path):
    path = write_scene_folder(tmp_path)
    (tmp_path / "meshes" / "ground.ply").write_text("this is not a mesh\n")
    with pytest.raises(MmwsimError, match="ground.ply: not a"):
        load_scene(path)
    (tmp_path / "meshes" / "buildings.obj").write_text("# only a comment\n")
    (tmp_path / "meshes" / "ground.ply").unlink()
    ground_mesh(0, 0, 100, 100).export(tmp_path / "meshes" / "ground.ply")
    with pytest.raises(MmwsimError, match="buildings.obj: not a triangle mesh"):
        load_scene(path)


def test_symlink_cannot_leave_folder(tmp_path):
    outside = tmp_path / "outside.ply"
    ground_mesh(0, 0, 100, 100).export(outside)
    path = write_scene_folder(tmp_path / "s")
    link = tmp_path / "s" / "meshes" / "link.ply"
    os.symlink(outside, link)
    _replace(path, 'mesh = "meshes/ground.ply"', 'mesh = "meshes/link.ply"')
    with pytest.raises(MmwsimError, match="leaves the scene folder"):
        load_scene(path)


@pytest.mark.parametrize(
    "old,new,message",
    [
        (
            '<string name="type" value="concrete"/>',
            '<string name="type" value="kryptonite"/>',
            "unknown material",
        ),
        ('value="meshes/towers.ply"', 'value="../towers.ply"', "leaves the scene folder"),
        ('value="meshes/towers.ply"', 'value="meshes/none.ply"', "mesh file not found"),
        ('<ref id="custom"/>', '<ref id="nothing"/>', "unknown material 'nothing'"),
        ('<shape type="ply" id="mesh-kiosk">', '<shape type="sphere" id="mesh-kiosk">', "unsupported shape"),
        ("</scene>", "", "malformed or unsafe XML"),
    ],
)
def test_mitsuba_errors(tmp_path, old, new, message):
    path = _replace(write_mitsuba(tmp_path), old, new)
    with pytest.raises(MmwsimError, match=message):
        load_scene(path)


def test_mitsuba_entity_expansion_is_refused(tmp_path):
    bomb = textwrap.dedent(
        """\
        <?xml version="1.0"?>
        <!DOCTYPE scene [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]>
        <scene version="2.1.0"><shape type="ply" id="x"><string name="filename" value="&b;"/></shape></scene>
        """
    )
    path = tmp_path / "bomb.xml"
    path.write_text(bomb)
    with pytest.raises(MmwsimError, match="unsafe XML"):
        load_scene(path)


def test_unknown_name_and_missing_file():
    with pytest.raises(MmwsimError, match="unknown scene 'atlantis'"):
        load_scene("atlantis")
    with pytest.raises(MmwsimError, match="file not found"):
        load_scene("/nonexistent/city.obj")
