"""run.mcap read back with the mcap reader: every step on /tf, the transforms composed give
the logged end effector (the kinematics' own numbers) to 1e-9, every log column on /log,
the robot description and the scene; one-line errors for runs that cannot make one."""

import csv
import json
import math

import numpy as np
import pytest
from mcap.decoder import DecoderFactory
from mcap.reader import make_reader

from aeromanip.cli import main
from aeromanip.errors import ConfigError
from aeromanip.experiment.runlog import RunLog
from aeromanip.experiment.runner import run_scenarios
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.viz import write_mcap, write_mcaps

pytest.importorskip("foxglove")
protobuf = pytest.importorskip("google.protobuf", reason="decodes the MCAP's protobuf messages")

EE_LINK = "end_effector"  # the x8-3dof's end-effector link (robots/x8-3dof.toml)


class Decoders(DecoderFactory):
    """JSON and protobuf (from the schema's FileDescriptorSet) messages to Python objects."""

    def decoder_for(self, message_encoding, schema):
        if message_encoding == "json":
            return lambda data: json.loads(data)
        if message_encoding == "protobuf":
            return _protobuf_class(schema).FromString
        return None


def _protobuf_class(schema):
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    pending = list(descriptor_pb2.FileDescriptorSet.FromString(schema.data).file)
    added: set[str] = set()
    while pending:  # dependencies first
        ready = [f for f in pending if set(f.dependency) <= added]
        assert ready, "unresolvable protobuf dependencies"
        for f in ready:
            pool.Add(f)
            added.add(f.name)
            pending.remove(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def read(path):
    """{topic: [(log_time, decoded message), ...]}, the summary and the attachments."""
    out = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[Decoders()])
        summary = reader.get_summary()
        for _, channel, message, decoded in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append((message.log_time, decoded))
        attachments = {a.name: a.data for a in reader.iter_attachments()}
    return out, summary, attachments


def rotation(q):
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def compose(transforms, child):
    """world -> ... -> ``child`` from one FrameTransforms message: its 4x4 pose."""
    by_child = {tf.child_frame_id: tf for tf in transforms}
    chain = [child]
    while chain[-1] in by_child:
        chain.append(by_child[chain[-1]].parent_frame_id)
    assert chain[-1] == "world", chain
    T = np.eye(4)
    for frame in reversed(chain[:-1]):
        tf = by_child[frame]
        A = np.eye(4)
        A[:3, :3] = rotation(tf.rotation)
        A[:3, 3] = [tf.translation.x, tf.translation.y, tf.translation.z]
        T = T @ A
    return T


@pytest.fixture(scope="module")
def kinematic_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("mcap") / "waypoints"
    run_scenarios(load_scenarios("waypoints", ["duration=3"]), out, progress=False, figures=False)
    return out


@pytest.fixture(scope="module")
def physics_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("mcap") / "physics"
    scenarios = load_scenarios("waypoints", ["duration=2", "sim=physics"], "hierarchical")
    run_scenarios(scenarios, out, progress=False, figures=False)
    return out / "hierarchical"


def check_run_mcap(run_dir):
    """Every check on one run directory's MCAP; returns the log read back."""
    path = write_mcap(run_dir)
    assert path == run_dir / "run.mcap"
    log = RunLog.load(run_dir)
    msgs, summary, attachments = read(path)
    schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert schemas == {
        "/tf": "foxglove.FrameTransforms",
        "/joint_states": "foxglove.JointStates",
        "/log": "aeromanip.LogRow",
        "/robot_description": "std_msgs/String",
        "/scene": "foxglove.SceneUpdate",
    }
    stamps = [round(t * 1e9) for t in log.column("t")]  # simulation time, every step
    for topic in ("/tf", "/joint_states", "/log"):
        assert [ns for ns, _ in msgs[topic]] == stamps, topic
    ee = np.stack([log.column(c) for c in ("ee_x", "ee_y", "ee_z")], axis=1)
    for k, (ns, m) in enumerate(msgs["/tf"]):
        assert {tf.timestamp.seconds * 10**9 + tf.timestamp.nanos for tf in m.transforms} == {ns}
        np.testing.assert_allclose(compose(m.transforms, EE_LINK)[:3, 3], ee[k], rtol=0, atol=1e-9)
    for k, (_, row) in enumerate(msgs["/log"]):
        assert set(row) == set(log.names)
        for name, col in log.columns.items():
            v = col[k].item()
            assert row[name] == v or (row[name] is None and isinstance(v, float) and math.isnan(v))
    q = [[j.position for j in m.joints] for _, m in msgs["/joint_states"]]
    np.testing.assert_array_equal(q, np.stack([log.column(f"q{i}") for i in (1, 2, 3)], axis=1))
    urdf = (run_dir / "robot.urdf").read_text()
    assert [m["data"] for _, m in msgs["/robot_description"]] == [urdf]
    assert attachments["robot.urdf"].decode() == urdf and "robot.xml" in attachments
    scene = {e.id: e for e in msgs["/scene"][0][1].entities}
    ref = [[p.x, p.y, p.z] for p in scene["reference"].lines[0].points]
    np.testing.assert_array_equal(ref, np.stack([log.column(f"ref_{c}") for c in "xyz"], axis=1))
    assert len(scene["waypoints"].spheres) == len(log.meta["waypoints"])
    assert len(scene["box_bounds"].lines[0].points) == 24  # z bounded: the 12 edges of a box
    layout = (run_dir / "foxglove-layout.json").read_text()  # a layout to import beside it
    assert json.loads(layout)["content"]["type"] == "split"
    assert '"topic":"/robot_description"' in layout and '"/log.ee_x"' in layout
    return log


def test_kinematic_runs_mcap_every_step_and_the_ee_to_1e_9(kinematic_run):
    paths = write_mcaps(kinematic_run)  # a scenario with variants: one MCAP each
    assert [p.parent.name for p in paths] == ["tracking-only", "hierarchical"]
    for variant in ("tracking-only", "hierarchical"):
        log = check_run_mcap(kinematic_run / variant)
        assert len(log) == 6


def test_physics_run_mcap_includes_roll_and_pitch(physics_run):
    log = check_run_mcap(physics_run)
    assert np.abs(log.column("roll")).max() > 1e-4  # the tilt is in the transforms


def test_cli_run_writes_run_mcap_by_default(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "waypoints", "--variant", "hierarchical", "--set", "duration=1",
                 "--out", str(out), "--quiet"]) == 0  # fmt: skip
    assert f"wrote {out / 'hierarchical' / 'run.mcap'}" in capsys.readouterr().out
    msgs, _, _ = read(out / "hierarchical" / "run.mcap")
    assert len(msgs["/tf"]) == len(RunLog.load(out / "hierarchical"))


def test_errors_are_one_line(tmp_path, kinematic_run):
    with pytest.raises(ConfigError, match="not a run directory"):
        write_mcap(tmp_path / "nothing")
    broken = tmp_path / "broken"
    broken.mkdir()
    for name in ("log.csv", "meta.json", "robot.xml"):
        (broken / name).write_bytes((kinematic_run / "hierarchical" / name).read_bytes())
    with pytest.raises(ConfigError, match=r"no robot\.urdf"):
        write_mcap(broken)
    urdf = (kinematic_run / "hierarchical" / "robot.urdf").read_text()
    (broken / "robot.urdf").write_text(urdf.replace('type="revolute"', 'type="fixed"', 1))
    with pytest.raises(ConfigError, match=r"2 movable joints, but the log has 3"):
        write_mcap(broken)
    (broken / "robot.urdf").write_text("<robot")
    with pytest.raises(ConfigError, match="malformed URDF") as e:
        write_mcap(broken)
    assert "\n" not in str(e.value)
    assert not list(broken.glob("*.mcap*"))  # nothing half-written left behind


def test_a_run_goes_on_without_the_viz_extra(kinematic_run, tmp_path, monkeypatch, capsys):
    from aeromanip.viz import export, mcap_log
    from aeromanip.viz.dependencies import MissingExtraError

    def missing(module, package, what):
        raise MissingExtraError(f"{what} needs the package {package!r}, not installed")

    monkeypatch.setattr(mcap_log, "require", missing)
    assert export.export_run(kinematic_run) == []
    err = capsys.readouterr().err
    assert "run.mcap not written: an MCAP log needs the package 'foxglove-sdk'" in err
    assert export.export_run(tmp_path) == []  # a run stopped before its first row
    assert "no log.csv here nor in its sub-directories" in capsys.readouterr().err


@pytest.fixture(scope="module")
def contact_run(tmp_path_factory):
    """contact-wall for 9 s: the approach, the touch near 7 s, 2 N held from 7 s."""
    out = tmp_path_factory.mktemp("mcap") / "contact"
    scenarios = load_scenarios("contact-wall", ["duration=9"], "cog")
    run_scenarios(scenarios, out, progress=False, figures=False)
    return out / "cog"


def _quat_apply(q, v):
    return rotation(q) @ np.asarray(v, dtype=float)


def test_contact_run_mcap_has_the_forces_of_log_csv_and_the_arrow(contact_run):
    path = write_mcap(contact_run)
    msgs, summary, _ = read(path)
    schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert schemas["/contact"] == "aeromanip.Contact"
    assert schemas["/contact/arrow"] == "foxglove.SceneUpdate"
    with (contact_run / "log.csv").open() as f:  # log.csv read as text, not by RunLog
        rows = list(csv.DictReader(f))
    stamps = [round(float(r["t"]) * 1e9) for r in rows]
    assert [ns for ns, _ in msgs["/contact"]] == stamps
    assert [ns for ns, _ in msgs["/contact/arrow"]] == stamps
    meta = json.loads((contact_run / "meta.json").read_text())
    radius = meta["probe_radius"]
    n = np.array(meta["surfaces"][0]["normal"])
    assert radius == 0.01 and n.tolist() == [-1.0, 0.0, 0.0]  # contact-wall's wall and probe
    arrows = 0
    for (_, m), (_, upd), r in zip(msgs["/contact"], msgs["/contact/arrow"], rows, strict=True):
        f = np.array([float(r[f"f_{c}"]) for c in "xyz"])
        assert [m["force"][c] for c in "xyz"] == f.tolist()
        assert [m["f_n"], m["f_t"], m["f_ref"], m["contact"]] == [
            float(r[c]) for c in ("f_n", "f_t", "f_ref", "contact")
        ]
        assert m["normal_force"] == pytest.approx(-f[0], abs=1e-15)  # the wall faces -x
        (entity,) = upd.entities
        assert entity.id == "contact_force" and entity.frame_id == "world"
        if float(r["contact"]) == 1.0 and -f[0] > 0:
            arrows += 1
            (a,) = entity.arrows
            tip = np.array([float(r[f"tip_{c}"]) for c in "xyz"])
            tail = [a.pose.position.x, a.pose.position.y, a.pose.position.z]
            np.testing.assert_allclose(tail, tip - radius * n, atol=1e-12)  # the contact point
            np.testing.assert_allclose(_quat_apply(a.pose.orientation, [1, 0, 0]), n, atol=1e-12)
            assert a.shaft_length + a.head_length == pytest.approx(0.1 * -f[0], rel=1e-12)
        else:
            assert not entity.arrows
    touching = sum(float(r["contact"]) == 1.0 for r in rows)
    assert arrows >= touching - 2 and arrows > 15  # pressing 2 N from about 7 s
    scene = {e.id: e for e in msgs["/scene"][0][1].entities}
    (cube,) = scene["surfaces"].cubes
    centre = [cube.pose.position.x, cube.pose.position.y, cube.pose.position.z]
    np.testing.assert_allclose(centre, [0.35, 0.0, 0.6], atol=1e-12)  # face at x = 0.3
    assert [cube.size.x, cube.size.y, cube.size.z] == [1.0, 0.4, 0.1]
    np.testing.assert_allclose(_quat_apply(cube.pose.orientation, [0, 0, 1]), n, atol=1e-12)
    np.testing.assert_allclose(_quat_apply(cube.pose.orientation, [0, 0.2, 0]), [0, 0, 0.2],
                               atol=1e-12)  # fmt: skip
    layout = (contact_run / "foxglove-layout.json").read_text()
    assert '"/contact.normal_force"' in layout and '"/contact/arrow"' in layout
