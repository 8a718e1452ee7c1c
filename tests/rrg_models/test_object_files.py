"""Objects as data: object folders, the installed catalogue, and ``rrg-object list/remove``."""

from __future__ import annotations

import hashlib
import os
import shutil
from dataclasses import replace

import numpy as np
import pytest
from goal_set_objects import GOAL_END, box_with_goal_end

from rrg_models.objects import (
    PAPER_OBJECTS,
    ObjectFileError,
    get_object,
    load_object_folder,
    object_folders,
    object_names,
)
from rrg_models.objects.catalogue import BUILTIN_DIR, USER_DIR_ENV
from rrg_onboarding import object_cli
from rrg_planner.request_checks import InvalidRequest, check_object

#: sha256 prefixes of everything a trial reads from each paper object (parts, mass,
#: friction, goal region, every WRT with its measured outcome, the settling study), bit for
#: bit, with the library versions of scripts/constraints.txt: a change here changes every
#: campaign, and says so.
CAMPAIGN_FINGERPRINTS = {
    "powerdrill": "bb1e77bfc295ae48",
    "brita_pitcher": "9acd064f8ab24988",
    "cooler": "0817d3e9c57849b6",
    "taperoll": "2ffaa29f000de508",
    "can": "963b1b3680de58f9",
    "wooden_bowl": "1cc657cb8b9c3c76",
    "cup": "2426080e904097b7",
    "teabox": "8c18bbb570a583a2",
    "box": "a51ba7578b621a6c",
    "giant_teacup": "5b9a0ccf018ce417",
}


def fingerprint(obj) -> str:
    """sha256 prefix over the exact bytes of everything a trial reads from ``obj``."""
    h = hashlib.sha256()

    def add(*values) -> None:
        for v in values:
            h.update(np.ascontiguousarray(np.asarray(v, dtype=float)).tobytes())

    for p in obj.parts:
        h.update(p.kind.encode())
        add(p.size, p.pos, p.quat)
    add(obj.mass, obj.friction, obj.goal.tol, obj.goal.min_fingers, obj.goal.theta_period)
    for rc in obj.goal.required_contacts:
        add(rc.parts, rc.fingers, rc.min_fingers)
    for w in obj.wrts():
        h.update(f"{w.name}/{w.kind}/{w.closure_informative}".encode())
        add(w.poses, w.spread, w.preclose, w.reorient_angle)
        if w.reorient_outcome is not None:
            add(w.reorient_outcome.box, w.reorient_outcome.shift, w.reorient_outcome.sigma)
    s = obj.grasp_settling
    if s is not None:
        add(s.box, s.closed.A, s.closed.b, s.closed.sigma, s.retreated.A, s.retreated.b)
        add(s.retreated.sigma, s.start, s.bandwidth)
        for k in sorted(s.samples):
            add(s.samples[k])
        if s.held is not None:
            add(s.held)
    return h.hexdigest()[:16]


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_the_paper_objects_load_from_data_bit_for_bit(name):
    assert fingerprint(get_object(name)) == CAMPAIGN_FINGERPRINTS[name]


def test_the_fingerprint_sees_a_change_in_the_last_bit():
    box = get_object("box")
    parts = list(box.parts)
    p = parts[0]
    parts[0] = type(p)(p.kind, p.size, (np.nextafter(p.pos[0], 1.0), *p.pos[1:]), p.quat)
    assert fingerprint(replace(box, parts=tuple(parts))) != CAMPAIGN_FINGERPRINTS["box"]


@pytest.fixture
def user_dir(tmp_path, monkeypatch):
    """An empty user objects folder named by RRG_OBJECTS_DIR."""
    folder = tmp_path / "objects"
    folder.mkdir()
    monkeypatch.setenv(USER_DIR_ENV, str(folder))
    return folder


def copy_builtin(source: str, name: str, dest) -> object:
    """A user object folder ``dest``/``name``: the built-in ``source`` renamed."""
    folder = dest / name
    shutil.copytree(BUILTIN_DIR / source, folder)
    text = (folder / "object.toml").read_text()
    (folder / "object.toml").write_text(text.replace(f'name = "{source}"', f'name = "{name}"'))
    return folder


def test_a_user_object_is_installed_by_its_folder_and_named_everywhere(user_dir):
    assert object_names() == PAPER_OBJECTS
    copy_builtin("box", "shoebox", user_dir)
    assert object_names() == (*PAPER_OBJECTS, "shoebox")
    obj = get_object("shoebox")
    assert obj.name == "shoebox" and obj.folder == user_dir / "shoebox"
    assert obj.grasp_settling is not None  # its studies came with it
    check_object("shoebox")  # the planner service takes it
    with pytest.raises(InvalidRequest) as err:
        check_object("hammer")
    assert err.value.code == "UNKNOWN_OBJECT" and "shoebox" in str(err.value)


def test_a_user_folder_never_shadows_a_built_in_object(user_dir):
    clash = copy_builtin("box", "cup", user_dir)
    assert object_folders()["cup"] == BUILTIN_DIR / "cup" != clash
    assert get_object("cup").mass == pytest.approx(0.118)


def test_an_edited_object_file_is_reloaded(user_dir):
    folder = copy_builtin("teabox", "tin", user_dir)
    assert get_object("tin").mass == pytest.approx(0.08)
    path = folder / "object.toml"
    text = path.read_text().replace("mass_kg = 0.08", "mass_kg = 0.2")
    path.write_text(text)
    os.utime(path, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns + 10**9))
    assert get_object("tin").mass == pytest.approx(0.2)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda t: t.replace("mass_kg = 0.3\n", ""), r"mass_kg: missing"),
        (lambda t: t.replace("mass_kg = 0.3", "mass_kg = -0.3"), r"mass_kg: must be > 0"),
        (lambda t: t.replace("mass_kg = 0.3", 'mass_kg = "heavy"'), r"mass_kg: expected a number"),
        (lambda t: t.replace('kind = "box"', 'kind = "torus"'), r"kind: unknown kind 'torus'"),
        (lambda t: t.replace('approach = "top_down"', 'approach = "below"'), r"unknown approach"),
        (lambda t: t.replace("through_m = [", "through_m = [0.0, "), r"through_m: expected 3"),
        (lambda t: t.replace('name = "box"', 'name = "crate"'), r"must match its folder"),
        (lambda t: t.replace("[goal_region]", "[goal_region\n"), r"object.toml: "),
        (lambda t: t.replace("tol = [0.015,", "tol = [0.0,"), r"tol: every tolerance must be > 0"),
        (
            lambda t: t.replace("[goal_region]", "[goal_region]\ncentre = [0.0]"),
            r"centre: expected 3",
        ),
        (
            lambda t: t + '\n[[goal_region.required_contacts]]\nname = "lid"\nparts = ["lid"]\n',
            r"no part called \['lid'\]",
        ),
        (
            lambda t: t + '\n[[parts]]\nname = "body"\nkind = "sphere"\nsize_m = [0.01]\n',
            r"part names must be unique",
        ),
    ],
)
def test_a_bad_object_file_names_its_file_and_key(tmp_path, edit, message):
    folder = tmp_path / "box"
    shutil.copytree(BUILTIN_DIR / "box", folder)
    path = folder / "object.toml"
    path.write_text(edit(path.read_text()))
    with pytest.raises(ObjectFileError, match=message) as err:
        load_object_folder(folder)
    assert str(path) in str(err.value)


def test_rrg_object_lists_every_object_and_removes_only_user_ones(user_dir, tmp_path, capsys):
    copy_builtin("can", "soup", user_dir)
    cache = tmp_path / "tables"
    cache.mkdir()
    for stem in ("soup__goal__0", "soup__sweep__1", "can__goal__0"):
        (cache / f"{stem}.npz").write_bytes(b"")
    assert object_cli.main(["list"]) == 0
    out = capsys.readouterr().out
    assert "soup" in out and "user" in out and "11 objects" in out
    assert "powerdrill" in out and "built-in" in out

    assert object_cli.main(["remove", "cup"]) == 2
    assert "built in" in capsys.readouterr().err and (BUILTIN_DIR / "cup").is_dir()
    assert object_cli.main(["remove", "hammer"]) == 2
    assert "installed: powerdrill" in capsys.readouterr().err

    assert object_cli.cached_tables("soup", cache) == sorted(cache.glob("soup__*"))
    assert object_cli.remove_object("soup", cache) == user_dir / "soup"
    assert not (user_dir / "soup").exists() and "soup" not in object_names()
    assert sorted(p.name for p in cache.iterdir()) == ["can__goal__0.npz"]


def test_rrg_objects_dir_is_a_search_path_whose_first_folder_wins(tmp_path, monkeypatch):
    first, second = tmp_path / "a", tmp_path / "b"
    first.mkdir(), second.mkdir()
    copy_builtin("teabox", "tin", first)
    copy_builtin("box", "tin", second)
    copy_builtin("can", "jar", second)
    monkeypatch.setenv(USER_DIR_ENV, os.pathsep.join([str(first), str(second)]))
    assert object_names() == (*PAPER_OBJECTS, "tin", "jar")
    assert object_folders()["tin"] == first / "tin" and get_object("tin").mass == pytest.approx(
        0.08
    )
    assert object_cli.user_objects_dir() == first  # where rrg-object add installs


def test_an_object_file_may_hold_several_goal_grasps(user_dir):
    """[[goal_grasps]]: each a named goal grasp with the object's tolerances (or its own,
    each > 0) about its own centre (default 0), its own settling study, and, for a side
    grasp, its own probe."""
    from rrg_models.objects.object_model import settling_file

    box_with_goal_end(user_dir, "shoebox", "centre = [0.0, 0.004, 0.0]\n")
    obj = get_object("shoebox")
    assert [g.name for g in obj.goal_grasps] == ["goal", "goal_end"]
    assert [w.name for w in obj.wrts()[:2]] == ["goal", "goal_end"]
    assert obj.wrt("goal_end").kind == "goal"
    end = obj.goal_region("goal_end")
    assert end.centre == (0.0, 0.004, 0.0) and end.tol == obj.goal.tol
    assert end.theta_period == obj.goal.theta_period == pytest.approx(np.pi)
    assert obj.grasp_settling is not None and obj.settling_for("goal_end") is None
    assert settling_file("realistic", "goal_end") == "goal_end.settling.realistic.json"
    assert settling_file("realistic") == "settling.realistic.json"
    with pytest.raises(KeyError, match="valid: \\['goal', 'goal_end'\\]"):
        obj.goal_region("goal3")

    wide = box_with_goal_end(user_dir, "widebox", "tol = [0.02, 0.025, 0.3]\n")
    assert get_object("widebox").goal_region("goal_end").tol == (0.02, 0.025, 0.3)
    assert get_object("widebox").goal.tol == obj.goal.tol
    (wide / "object.toml").write_text(
        (wide / "object.toml").read_text().replace("[0.02, 0.025, 0.3]", "[0.02, 0.0, 0.3]")
    )
    with pytest.raises(ObjectFileError, match=r"\[\[goal_grasps\]\].*tol.*must be > 0"):
        load_object_folder(wide)

    side = copy_builtin("can", "soup", user_dir) / "object.toml"
    grasp = side.read_text().split("[goal_grasp]")[1].split("\n\n")[0]
    side.write_text(side.read_text() + '\n[[goal_grasps]]\nname = "goal2"' + grasp + "\n")
    probes = [w for w in get_object("soup").info_wrts if "probe_of" in w.meta]
    assert [(w.name, w.meta["probe_of"]) for w in probes] == [
        ("goal_probe", "goal"),
        ("goal2_probe", "goal2"),
    ]


def test_a_goal_grasps_wrt_is_found_without_generating_the_others(user_dir):
    """A settling study or a ranking grasp asks only for its goal grasp's WRT: the object's
    information WRTs (a pinch search over every part) are not generated for it; any other
    WRT's lookup generates them, and names them when it is missing."""
    box_with_goal_end(user_dir, "crate", "")
    obj = load_object_folder(user_dir / "crate")
    assert obj.wrt("goal_end").kind == "goal" and obj.wrt("goal").kind == "goal"
    assert "info_wrts" not in vars(obj) and "_wrts" not in vars(obj)
    assert obj.wrt("sweep").kind == "info" and "info_wrts" in vars(obj)
    with pytest.raises(KeyError, match="has no WRT 'goal9'"):
        obj.wrt("goal9")


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("grasp2", "a goal grasp's name is goal and a suffix"),
        ("goal2_probe", "a goal grasp's name is goal and a suffix"),
        ("goal", "a goal grasp's name is goal and a suffix"),
        ("goal_end", "goal grasp names must be unique"),
    ],
)
def test_a_goal_grasp_with_a_bad_or_repeated_name_is_refused(tmp_path, name, message):
    folder = box_with_goal_end(tmp_path, "box", GOAL_END.replace('"goal_end"', f'"{name}"'))
    with pytest.raises(ObjectFileError, match=message):
        load_object_folder(folder)
