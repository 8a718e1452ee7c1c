"""The Foxglove layout (docs/foxglove/rrg_layout.json) and the RViz config (docs/rviz/rrg.rviz)
name only what the main job's bag has: every topic they name is in the bag with the schema they
expect, every Foxglove message path (``/topic{filter}.field[index].field``) resolves field by
field in the bag's own message definitions (its MCAP schema records), every filter compares a
field with a value of its type, and every tf frame they name is in the bag's /tf or /tf_static.
The checker is shown to fail on a misspelt field, topic, filter or frame."""

from __future__ import annotations

import copy
import json
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
LAYOUT = ROOT / "docs" / "foxglove" / "rrg_layout.json"
RVIZ = ROOT / "docs" / "rviz" / "rrg.rviz"

PRIMITIVES = {
    "bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64",
    "uint64", "float32", "float64", "string", "wstring",
}  # fmt: skip
NUMERIC = PRIMITIVES - {"bool", "string", "wstring"}
#: What each RViz display reads, by its class.
RVIZ_TYPES = {
    "rviz_default_plugins/RobotModel": "std_msgs/msg/String",
    "rviz_default_plugins/MarkerArray": "visualization_msgs/msg/MarkerArray",
    "rviz_default_plugins/Marker": "visualization_msgs/msg/Marker",
}
#: Panels whose message paths must end on a value (a plot's y, a state, an indicator's input).
VALUE_PANELS = ("Plot", "StateTransitions", "Indicator")


# ------------------------------------------------------------------ message definitions
@dataclass(frozen=True)
class Field:
    type: str  # "float64", or a message type "pkg/Name"
    name: str
    array: bool


def parse_ros2msg(schema_name: str, text: str) -> dict[str, dict[str, Field]]:
    """The message definitions of an MCAP ``ros2msg`` schema (the definition of ``schema_name``,
    then each dependency after a ``====`` line and ``MSG: pkg/Name``), as {"pkg/Name": {field
    name: Field}}; constants (``uint8 EVENT_DONE=2``) are not fields."""
    defs: dict[str, dict[str, Field]] = {}
    current = normalize(schema_name)
    defs[current] = {}
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if re.fullmatch(r"=+", line):
            current = None
            continue
        if line.startswith("MSG:"):
            current = normalize(line.split(":", 1)[1].strip())
            defs[current] = {}
            continue
        assert current is not None, f"no MSG: line after a separator in {schema_name}"
        m = re.fullmatch(r"(\S+)\s+([A-Za-z_]\w*)\s*(=.*)?(\s+.*)?", line)
        assert m, f"{schema_name}: cannot parse {raw!r}"
        type_, name, constant = m[1], m[2], m[3]
        if constant:
            continue
        array = "[" in type_
        base = re.sub(r"\[.*\]$", "", type_)
        base = re.sub(r"<=\d+$", "", base)  # bounded strings
        if base not in PRIMITIVES:
            if base == "Header":
                base = "std_msgs/Header"
            elif "/" not in base:  # a type of the same package
                base = current.split("/")[0] + "/" + base
            base = normalize(base)
        defs[current][name] = Field(base, name, array)
    return defs


def normalize(type_name: str) -> str:
    """``pkg/msg/Name`` and ``pkg/Name`` alike as ``pkg/Name``."""
    parts = type_name.split("/")
    return f"{parts[0]}/{parts[-1]}"


# ------------------------------------------------------------------ Foxglove message paths
@dataclass(frozen=True)
class MessagePath:
    topic: str
    steps: tuple  # ("field", name) | ("index", text) | ("filter", field path, value text)
    function: str | None  # a trailing .@abs etc.


PATH_TOKEN = re.compile(
    r"\.(?P<field>[A-Za-z_]\w*)|\[(?P<index>[^\]]*)\]|\{(?P<filter>[^}]*)\}|\.@(?P<func>\w+)"
)


def parse_message_path(text: str) -> MessagePath:
    """Foxglove's message path syntax: a topic, then fields, indexes/slices and filters."""
    m = re.match(r"/[A-Za-z0-9_/]*[A-Za-z0-9_]", text)
    if not m:
        raise ValueError(f"{text!r}: no topic")
    topic, pos, steps, function = m[0], m.end(), [], None
    while pos < len(text):
        t = PATH_TOKEN.match(text, pos)
        if not t or function is not None:
            raise ValueError(f"{text!r}: cannot parse from {text[pos:]!r}")
        if t["field"]:
            steps.append(("field", t["field"]))
        elif t["index"] is not None:
            if not re.fullmatch(r"\s*(-?\d+|\$\w+)?\s*(:\s*(-?\d+|\$\w+)?\s*)?", t["index"]):
                raise ValueError(f"{text!r}: bad index [{t['index']}]")
            steps.append(("index", t["index"]))
        elif t["filter"] is not None:
            f = re.fullmatch(r"\s*([A-Za-z_][\w.]*)\s*==\s*(.+?)\s*", t["filter"])
            if not f:
                raise ValueError(f"{text!r}: bad filter {{{t['filter']}}}")
            steps.append(("filter", f[1], f[2]))
        else:
            function = t["func"]
        pos = t.end()
    return MessagePath(topic, tuple(steps), function)


def value_fits(field: Field, value: str) -> bool:
    """Whether a filter's value can equal the field's values (``$var`` always can)."""
    if value.startswith("$"):
        return True
    if field.array or field.type not in PRIMITIVES:
        return False
    if field.type == "bool":
        return value in ("true", "false")
    if field.type in ("string", "wstring"):
        return bool(re.fullmatch(r"'[^']*'|\"[^\"]*\"", value))
    return bool(re.fullmatch(r"-?\d+(\.\d+)?", value))


def resolve(path: MessagePath, root: str, defs: dict, need_value: bool) -> list[str]:
    """What does not resolve in ``path`` against the message type ``root`` (empty: it all does)."""
    problems = []
    field = Field(root, "", False)  # where the path is: a message, an array, or a value
    for step in path.steps:
        if step[0] == "index":
            if not field.array:
                problems.append(f"[{step[1]}] indexes {field.name or root}, not an array")
                return problems
            field = Field(field.type, field.name, False)
            continue
        if field.array or field.type in PRIMITIVES:
            problems.append(f"{step} after {field.name or root}, which is not a message")
            return problems
        fields = defs.get(field.type)
        if fields is None:
            problems.append(f"no definition of {field.type}")
            return problems
        if step[0] == "field":
            if step[1] not in fields:
                problems.append(f"{field.type} has no field {step[1]!r}")
                return problems
            field = fields[step[1]]
        else:  # a filter on the message here: its field path must lead to a value
            _, filter_path, value = step
            sub = resolve(
                MessagePath(path.topic, tuple(("field", f) for f in filter_path.split(".")), None),
                field.type,
                defs,
                need_value=True,
            )
            if sub:
                problems += [f"filter {{{filter_path}=={value}}}: {p}" for p in sub]
                return problems
            target = last_field(filter_path, field.type, defs)
            if not value_fits(target, value):
                problems.append(
                    f"filter {{{filter_path}=={value}}}: {value} is not a {target.type} value"
                )
    if need_value and (field.array or field.type not in PRIMITIVES):
        problems.append(f"ends on {field.type}{'[]' if field.array else ''}, not a value")
    if need_value and path.function and field.type not in NUMERIC:
        problems.append(f".@{path.function} of a {field.type}")
    return problems


def last_field(dotted: str, root: str, defs: dict) -> Field:
    field = Field(root, "", False)
    for name in dotted.split("."):
        field = defs[field.type][name]
    return field


# ------------------------------------------------------------------ what the configs name
@dataclass(frozen=True)
class Reference:
    where: str  # the panel or display, for messages
    topic: str
    path: MessagePath | None = None  # None: the topic only
    schema: str | None = None  # the schema the topic must have (None: any)
    need_value: bool = False


def layout_references(layout: dict) -> tuple[list[Reference], set[str]]:
    """Every topic and message path a Foxglove layout's panels name, and every tf frame."""
    refs, frames = [], set()
    for panel_id, config in layout["configById"].items():
        kind = panel_id.split("!")[0]
        paths: list[str] = []
        if kind in ("Plot", "StateTransitions"):
            paths = [p["value"] for p in config.get("paths", [])]
            if config.get("xAxisPath"):
                paths.append(config["xAxisPath"]["value"])
        elif kind == "Indicator":
            paths = [config["path"]]
        elif kind in ("RawMessages", "Table"):
            paths = [config["topicPath"]]
        elif kind == "3D":
            for topic, settings in config.get("topics", {}).items():
                if settings and settings.get("visible", True):
                    schema = {"/robot_description": "std_msgs/String"}.get(topic)
                    refs.append(Reference(panel_id, topic, schema=schema))
            frames |= {k.removeprefix("frame:") for k in config.get("transforms", {})}
            frames |= {x["frameId"] for x in config.get("layers", {}).values() if "frameId" in x}
            frames.add(config["followTf"])
        else:
            raise AssertionError(f"{panel_id}: a panel this test does not know how to check")
        for text in paths:
            parsed = parse_message_path(text)
            need_value = kind in VALUE_PANELS
            refs.append(Reference(panel_id, parsed.topic, parsed, need_value=need_value))
    return refs, frames


def rviz_references(config: dict) -> tuple[list[Reference], set[str]]:
    """Every topic an RViz config's displays subscribe (with the type the display reads) and
    every tf frame it names."""
    refs, frames = [], set()
    manager = config["Visualization Manager"]
    frames.add(manager["Global Options"]["Fixed Frame"])

    def walk(displays):
        for d in displays:
            if d.get("Class") == "rviz_common/Group":
                walk(d.get("Displays", []))
                continue
            topic = (d.get("Topic") or d.get("Description Topic") or {}).get("Value")
            if d["Class"] == "rviz_default_plugins/RobotModel":
                assert d["Description Source"] == "Topic", d
            if topic:
                assert d["Class"] in RVIZ_TYPES, f"{d['Name']}: a display this test does not know"
                refs.append(Reference(d["Name"], topic, schema=RVIZ_TYPES[d["Class"]]))
            if d["Class"] == "rviz_default_plugins/TF":
                frames.update(k for k in d["Frames"] if k != "All Enabled")
            if "Reference Frame" in d and d["Reference Frame"] != "<Fixed Frame>":
                frames.add(d["Reference Frame"])

    walk(manager["Displays"])
    frames.add(manager["Views"]["Current"]["Target Frame"])
    return refs, frames


# ------------------------------------------------------------------ the bag
@dataclass
class BagFacts:
    schemas: dict[str, tuple[str, dict]]  # topic -> (schema name "pkg/Name", its definitions)
    frames: set[str]  # every frame in /tf and /tf_static, parents and children


def bag_facts(mcap: Path) -> BagFacts:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    schemas, frames = {}, set()
    with mcap.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            assert schema.encoding == "ros2msg", schema.encoding
            name = normalize(schema.name)
            schemas[channel.topic] = (name, parse_ros2msg(name, schema.data.decode()))
        for _, _, _, tf in reader.iter_decoded_messages(topics=["/tf", "/tf_static"]):
            for t in tf.transforms:
                frames |= {t.header.frame_id, t.child_frame_id}
    return BagFacts(schemas, frames)


def check(refs: list[Reference], frames: set[str], bag: BagFacts) -> list[str]:
    """Every reference and frame that the bag does not have, in words (empty: none)."""
    problems = []
    for r in refs:
        text = r.topic + (
            "".join(
                f".{s[1]}" if s[0] == "field" else f"[{s[1]}]" if s[0] == "index" else "{..}"
                for s in r.path.steps
            )
            if r.path
            else ""
        )
        if r.topic not in bag.schemas:
            problems.append(f"{r.where}: no topic {r.topic} in the bag")
            continue
        schema, defs = bag.schemas[r.topic]
        if r.schema and normalize(r.schema) != schema:
            problems.append(f"{r.where}: {r.topic} is {schema} in the bag, not {r.schema}")
        if r.path:
            problems += [
                f"{r.where}: {text}: {p}" for p in resolve(r.path, schema, defs, r.need_value)
            ]
    problems += [f"no tf frame {f!r} in the bag" for f in sorted(frames - bag.frames)]
    return problems


# ------------------------------------------------------------------ fast checks (no bag)
def test_every_layout_path_parses_and_names_rrg_messages():
    layout = json.loads(LAYOUT.read_text())
    refs, frames = layout_references(layout)
    topics = {r.topic for r in refs}
    assert {"/robot_description", "/rrg/belief_markers", "/rrg/grasp_step",
            "/rrg/fingertip1/wrench", "/rrg/fingertip2/wrench", "/rrg/fingertip3/wrench",
            "/rrg/observation", "/rrg/eval/grasp_outcome"} <= topics  # fmt: skip
    assert {"world", "object_estimate", "object_true"} <= frames
    # the layout tree names exactly the configured panels
    in_tree = set(re.findall(r'"([A-Za-z0-9]+![A-Za-z0-9_-]+)"', json.dumps(layout["layout"])))
    assert in_tree == set(layout["configById"])


def test_message_path_parser():
    p = parse_message_path("/rrg/grasp_step{event==0}.estimate.theta")
    steps = (("filter", "event", "0"), ("field", "estimate"), ("field", "theta"))
    assert p == MessagePath("/rrg/grasp_step", steps, None)
    p = parse_message_path(
        '/tf.transforms[:]{child_frame_id=="object_true"}.transform.rotation.z.@abs'
    )
    assert p.steps[1] == ("index", ":") and p.function == "abs"
    for bad in ("rrg/grasp_step.p_goal", "/rrg/grasp_step..p_goal", "/rrg/x{event=0}.a"):
        with pytest.raises(ValueError):
            parse_message_path(bad)


def test_the_checker_reports_a_misspelt_field_against_rrg_msgs_definitions():
    """Against GraspStep's definition as a bag stores it (built here from rrg_msgs/msg)."""
    msg = ROOT / "rrg_msgs" / "msg"
    text = (msg / "GraspStep.msg").read_text()
    for dep, body in [
        ("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"),
        ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
        ("rrg_msgs/PlanarPose", (msg / "PlanarPose.msg").read_text()),
    ]:
        text += f"{'=' * 80}\nMSG: {dep}\n{body}"
    defs = parse_ros2msg("rrg_msgs/msg/GraspStep", text)
    assert "EVENT_DONE" not in defs["rrg_msgs/GraspStep"]  # a constant, not a field
    bag = BagFacts({"/rrg/grasp_step": ("rrg_msgs/GraspStep", defs)}, {"world"})

    def problems(path: str) -> list[str]:
        ref = Reference("Plot!x", "/rrg/grasp_step", parse_message_path(path), need_value=True)
        return check([ref], set(), bag)

    assert problems("/rrg/grasp_step{event==0}.p_goal") == []
    assert problems("/rrg/grasp_step.estimate.theta") == []
    assert problems("/rrg/grasp_step.header.stamp.sec") == []
    assert problems("/rrg/grasp_step.action_values[0]") == []
    assert "has no field 'p_gaol'" in problems("/rrg/grasp_step{event==0}.p_gaol")[0]
    assert "has no field 'evnt'" in problems("/rrg/grasp_step{evnt==0}.p_goal")[0]
    assert "is not a uint8 value" in problems("/rrg/grasp_step{event=='done'}.p_goal")[0]
    assert "not a value" in problems("/rrg/grasp_step.estimate")[0]
    assert "not an array" in problems("/rrg/grasp_step.p_goal[0]")[0]
    assert "no topic" in check([Reference("x", "/rrg/grasp_steps")], set(), bag)[0]
    assert "no tf frame 'objekt_true'" in check([], {"objekt_true"}, bag)[0]


# ------------------------------------------------------------------ the main job's bag
@pytest.fixture(scope="module")
def main_job_bag(tmp_path_factory, ros_domain) -> Path:
    """The main job (scripts/run.sh: the power drill at high uncertainty with RRG-Info, seed 0)
    run by rrg-launch in a DDS domain of the test's own; its bag's .mcap file."""
    from ros_testing import ros_env

    tmp = tmp_path_factory.mktemp("main_job")
    args = [sys.executable, "-m", "rrg_bringup.launch", "--mode", "sim"]
    args += ["--grasp", "powerdrill", "--level", "high", "--strategy", "rrg-info", "--seed", "0"]
    args += ["--domain-id", str(ros_domain), "--bags", str(tmp), "--bag-name", "main"]
    args += ["--log-dir", str(tmp / "logs"), "--json"]
    out = subprocess.run(
        args, env=ros_env(ros_domain), cwd=ROOT, capture_output=True, text=True, timeout=900
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    (mcap,) = sorted((tmp / "main").glob("*.mcap"))
    return mcap


@pytest.fixture(scope="module")
def main_job_facts(main_job_bag) -> BagFacts:
    return bag_facts(main_job_bag)


@pytest.mark.slow  # the launcher's node processes
def test_the_layout_names_only_what_the_main_jobs_bag_has(main_job_facts):
    refs, frames = layout_references(json.loads(LAYOUT.read_text()))
    assert check(refs, frames, main_job_facts) == []
    # the panels' schemas: the topics the layout is about have the types it was written for
    schemas = {t: s for t, (s, _) in main_job_facts.schemas.items()}
    assert schemas["/rrg/grasp_step"] == "rrg_msgs/GraspStep"
    assert schemas["/rrg/eval/grasp_outcome"] == "rrg_msgs/GraspOutcome"
    assert schemas["/rrg/observation"] == "rrg_msgs/Observation"
    assert schemas["/rrg/belief_markers"] == "visualization_msgs/MarkerArray"
    assert schemas["/rrg/fingertip1/wrench"] == "geometry_msgs/WrenchStamped"


@pytest.mark.slow  # the launcher's node processes
def test_the_rviz_config_names_only_what_the_main_jobs_bag_has(main_job_facts):
    config = yaml.safe_load(RVIZ.read_text())
    refs, frames = rviz_references(config)
    assert {r.topic for r in refs} == {"/robot_description", "/rrg/belief_markers"}
    assert {"world", "object_estimate", "object_true"} <= frames
    assert check(refs, frames, main_job_facts) == []


@pytest.mark.slow  # the launcher's node processes
def test_a_misspelt_layout_is_reported(main_job_facts, tmp_path):
    """A copy of the layout with one mistake of each kind: each is reported, and nothing else."""
    layout = copy.deepcopy(json.loads(LAYOUT.read_text()))
    panels = layout["configById"]
    plot = next(k for k in panels if k.startswith("Plot!"))
    panels[plot]["paths"][0]["value"] = "/rrg/grasp_step{event==0}.p_gaol"
    panels[plot]["paths"].append(
        {"value": "/rrg/grasp_steps.p_goal", "enabled": True, "timestampMethod": "receiveTime"}
    )
    panels[plot]["paths"].append(
        {
            "value": "/rrg/fingertip1/wrench.wrench.force",
            "enabled": True,
            "timestampMethod": "receiveTime",
        }
    )
    indicator = next(k for k in panels if k.startswith("Indicator!"))
    panels[indicator]["path"] = "/rrg/eval/grasp_outcome{sucess==true}.success"
    three_d = next(k for k in panels if k.startswith("3D!"))
    panels[three_d]["transforms"]["frame:objekt_true"] = {"visible": True}
    panels[three_d]["topics"]["/rrg/belief_marker"] = {"visible": True}
    copy_path = tmp_path / "rrg_layout.json"
    copy_path.write_text(json.dumps(layout))
    refs, frames = layout_references(json.loads(copy_path.read_text()))
    problems = check(refs, frames, main_job_facts)
    assert len(problems) == 6, problems
    text = "\n".join(problems)
    assert "GraspStep has no field 'p_gaol'" in text
    assert "no topic /rrg/grasp_steps in the bag" in text
    assert "ends on geometry_msgs/Vector3, not a value" in text
    assert "GraspOutcome has no field 'sucess'" in text
    assert "no tf frame 'objekt_true'" in text
    assert "no topic /rrg/belief_marker in the bag" in text


@pytest.mark.slow  # the launcher's node processes
def test_an_rviz_config_with_a_wrong_topic_or_type_is_reported(main_job_facts):
    config = yaml.safe_load(RVIZ.read_text())
    displays = config["Visualization Manager"]["Displays"]
    markers = next(d for d in displays if d["Class"] == "rviz_default_plugins/MarkerArray")
    markers["Topic"]["Value"] = "/rrg/belief"  # a BeliefGrid, not a MarkerArray
    config["Visualization Manager"]["Global Options"]["Fixed Frame"] = "map"
    problems = check(*rviz_references(config), main_job_facts)
    assert problems == [
        "Belief (heaviest grid points): /rrg/belief is rrg_msgs/BeliefGrid in the bag, not "
        "visualization_msgs/msg/MarkerArray",
        "no tf frame 'map' in the bag",
    ]


FOXGLOVE_MODULES = ROOT / ".cache" / "foxglove" / "node_modules"


@pytest.mark.slow  # the launcher's node processes and a headless browser
def test_foxglove_studio_opens_the_main_jobs_bag_with_the_layout(main_job_bag, tmp_path):
    """scripts/foxglove_screenshot.cjs: the real app loads the bag and the layout, draws the 3D
    panel and exits without a page error; the screenshot is a full-size PNG."""
    assert (FOXGLOVE_MODULES / "@foxglove" / "studio-base").is_dir() and Path(
        "/usr/bin/chromium"
    ).exists(), "Foxglove Studio's web build or Chromium is missing: run scripts/setup_foxglove.sh"
    png = tmp_path / "layout.png"
    out = subprocess.run(
        ["node", str(ROOT / "scripts" / "foxglove_screenshot.cjs"), str(main_job_bag)]
        + ["--out", str(png), "--size", "1200x800", "--wait", "5"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "in Foxglove Studio" in out.stdout
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(data[16:20], "big") == 1200 and int.from_bytes(data[20:24], "big") == 800


@pytest.mark.slow  # the launcher's node processes
def test_the_main_jobs_bag_holds_the_robots_frames_and_every_nodes_health(main_job_bag):
    """Foxglove's own readers decode /tf, /tf_static, /robot_description and /diagnostics of
    the main job's bag, and the frames put the palm and the fingertips where the project's
    forward kinematics does at the recorded joint states (bag_frames.check_frames, 1e-6 m)."""
    from bag_frames import check_frames
    from ros_testing import foxglove_read

    decoded = foxglove_read(main_job_bag)
    expected = {
        "/tf": "tf2_msgs/msg/TFMessage",
        "/tf_static": "tf2_msgs/msg/TFMessage",
        "/robot_description": "std_msgs/msg/String",
        "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    }
    for topic, schema in expected.items():
        found = decoded["topics"][topic]
        same = found["schema"].replace("/msg/", "/") == schema.replace("/msg/", "/")
        assert same and found["count"] > 0, (topic, found)
    assert decoded["last"]["/robot_description"]["data"].startswith("<robot ")
    assert "bh_f3_tip" in decoded["last"]["/robot_description"]["data"]
    assert decoded["last"]["/diagnostics"]["status"][0]["name"].endswith(": status")
    checked, states = check_frames(main_job_bag.parent)
    assert checked >= 0.9 * states and states >= 20, (checked, states)
