"""Scene bundles: every file stays inside the bundle, checked before Mitsuba parses anything."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from holocore.scene.bundle import BundleError, BundleLimits, validate_bundle
from tests.project_scenes import SCENE_SOURCES

SCENE = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="30"/></sensor>
  {body}
</scene>
"""


def bundle(tmp_path: Path, body: str, files: dict[str, bytes] | None = None) -> Path:
    root = tmp_path / "b"
    root.mkdir()
    (root / "scene.xml").write_text(SCENE.format(body=body))
    for name, data in (files or {}).items():
        p = root / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    return root


OBJ = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"


@pytest.mark.parametrize("source", SCENE_SOURCES)
def test_scene_bundles_pass(bundles_of, source):
    bundles = bundles_of(source)
    for name in ("cbox-mirror-glass", "veach-bidir", "veach-mis"):
        rep = validate_bundle(bundles.folder(name), entry=bundles.entry(name).name)
        assert rep.entry.suffix == ".xml" and rep.sha256 and rep.total_bytes > 0
    cbox = validate_bundle(bundles.folder("cbox-mirror-glass"))
    assert "shape:obj" in cbox.plugins and "meshes/cbox_floor.obj" in cbox.files and cbox.entry.name == "cbox.xml"


def test_relative_mesh_inside_passes_and_hash_is_content_addressed(tmp_path):
    root = bundle(tmp_path, '<shape type="obj"><string name="filename" value="meshes/a.obj"/></shape>',
                  {"meshes/a.obj": OBJ})
    rep = validate_bundle(root)
    assert rep.files == ["meshes/a.obj", "scene.xml"] and rep.mesh_faces == 1
    (root / "meshes/a.obj").write_bytes(OBJ + b"f 1 3 2\n")
    assert validate_bundle(root).sha256 != rep.sha256


@pytest.mark.parametrize("value, words", [
    ("/etc/passwd", "absolute path"),
    ("../outside.obj", "leaves the scene bundle"),
    ("meshes/../../outside.obj", "leaves the scene bundle"),
    ("C:/Windows/x.obj", "absolute path"),
    ("missing.obj", "not in the bundle"),
])
def test_escaping_or_missing_files_are_refused(tmp_path, value, words):
    (tmp_path / "outside.obj").write_bytes(OBJ)
    root = bundle(tmp_path, f'<shape type="obj"><string name="filename" value="{value}"/></shape>')
    with pytest.raises(BundleError, match=words):
        validate_bundle(root)


def test_include_leaving_the_bundle_and_path_elements_are_refused(tmp_path):
    (tmp_path / "evil.xml").write_text('<scene version="3.0.0"/>')
    with pytest.raises(BundleError, match="leaves the scene bundle"):
        validate_bundle(bundle(tmp_path, '<include filename="../evil.xml"/>'))
    other = tmp_path / "o"
    other.mkdir()
    with pytest.raises(BundleError, match="<path>"):
        validate_bundle(bundle(other, '<path value="/usr/share"/>'))


def test_symlink_out_of_the_bundle_is_refused(tmp_path):
    secret = tmp_path / "secret.obj"
    secret.write_bytes(OBJ)
    root = bundle(tmp_path, '<shape type="obj"><string name="filename" value="link.obj"/></shape>')
    os.symlink(secret, root / "link.obj")
    with pytest.raises(BundleError, match="symbolic link"):
        validate_bundle(root)


def test_entity_bomb_and_unknown_plugins_are_refused(tmp_path):
    root = tmp_path / "bomb"
    root.mkdir()
    (root / "scene.xml").write_text('<?xml version="1.0"?><!DOCTYPE s [<!ENTITY a "aaaaaaaaaa">'
                                    '<!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;">]><scene>&b;</scene>')
    with pytest.raises(BundleError, match="DTD"):
        validate_bundle(root)
    with pytest.raises(BundleError, match="disallowed bsdf plugin 'evil'"):
        validate_bundle(bundle(tmp_path, '<bsdf type="evil"/>'))


def test_caps_on_faces_and_files(tmp_path):
    root = bundle(tmp_path, '<shape type="obj"><string name="filename" value="a.obj"/></shape>', {"a.obj": OBJ * 5})
    with pytest.raises(BundleError, match="faces"):
        validate_bundle(root, limits=BundleLimits(max_mesh_faces=3))
    with pytest.raises(BundleError, match="more than 1 files"):
        validate_bundle(root, limits=BundleLimits(max_files=1))
