"""Model files: MJCF and URDF variants (zero/negative/NaN mass, bad inertia, NaN attributes, unsupported
features, free joints, odd extensions, URDF saved as .xml), each through `linearize`, `crosscheck` and `run`."""

from __future__ import annotations

from pathlib import Path

from fixtures import dump_toml, write_text
from harness import Probe

CAT = "model"

PENDULUM = """<mujoco model="pend">
  <compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="{timestep}" gravity="{gravity}" integrator="Euler">
    <flag eulerdamp="disable" contact="disable"/>
  </option>
  <worldbody>
    <body name="pole" pos="0 0 0">
      {joint}
      {inertial}
      <geom name="rod" type="capsule" fromto="0 0 0 0 0 0.5" size="0.01" contype="0" conaffinity="0" density="0"/>
    </body>
    {extra_body}
  </worldbody>
  {extra}
  <actuator>
    {actuator}
  </actuator>
</mujoco>
"""
DEFAULTS = {
    "timestep": "0.01",
    "gravity": "0 0 -9.81",
    "joint": '<joint name="hinge" type="hinge" axis="0 1 0" damping="0.01"/>',
    "inertial": '<inertial pos="0 0 0.5" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/>',
    "extra_body": "",
    "extra": "",
    "actuator": '<motor name="m" joint="hinge" gear="1"/>',
}


SECOND_BODY = (
    '<body name="b2" pos="1 0 0"><joint name="h2" type="hinge" axis="0 1 0"/>'
    '<inertial pos="0 0 0.5" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/></body>'
)


def mjcf(**kw: str) -> str:
    return PENDULUM.format(**{**DEFAULTS, **kw})


URDF = """<?xml version="1.0"?>
<robot name="twolink">
  <link name="base"/>
  <link name="l1">
    {inertial1}
  </link>
  <joint name="j1" type="{jtype}">
    <parent link="base"/><child link="l1"/>
    <origin xyz="{origin}" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="10" velocity="10"/>
    {jextra}
  </joint>
  {extra}
</robot>
"""
U_DEFAULTS = {
    "inertial1": '<inertial><origin xyz="0 0 0.5"/><mass value="0.1"/>'
    '<inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial>',
    "jtype": "revolute",
    "origin": "0 0 0",
    "jextra": "",
    "extra": "",
}


MIMIC = (
    '<link name="l2"><inertial><mass value="0.1"/><inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy'
    '="0" ixz="0" iyz="0"/></inertial></link><joint name="j2" type="revolute"><parent link="l1"'
    '/><child link="l2"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"'
    '/><mimic joint="j1"/></joint>'
)


def urdf(**kw: str) -> str:
    return URDF.format(**{**U_DEFAULTS, **kw})


def _variants() -> list[tuple[str, str, str | bytes, str, tuple[str, ...]]]:
    """(name, filename, content, expectation, needles)."""
    v: list[tuple[str, str, str | bytes, str, tuple[str, ...]]] = []
    r = "refuse"
    e = "either"
    v.append(("mjcf_ok", "m.xml", mjcf(), "ok", ()))
    for mass, exp in (("0", r), ("-1", r), ("nan", r), ("inf", r), ("1e300", e), ("1e-12", e)):
        v.append(
            (
                f"mass_{mass}",
                "m.xml",
                mjcf(inertial=f'<inertial pos="0 0 0.5" mass="{mass}" diaginertia="1e-4 1e-4 1e-4"/>'),
                exp,
                ("mass", "pole", "inertia"),
            )
        )
    for inertia, exp in (("0 0 0", e), ("-1 1 1", r), ("nan 1 1", r), ("1 1 5", r)):
        v.append(
            (
                f"inertia_{inertia.replace(' ', '_')}",
                "m.xml",
                mjcf(inertial=f'<inertial pos="0 0 0.5" mass="0.1" diaginertia="{inertia}"/>'),
                exp,
                ("inertia", "pole"),
            )
        )
    v.append(
        (
            "fullinertia_not_pd",
            "m.xml",
            mjcf(inertial='<inertial pos="0 0 0.5" mass="0.1" fullinertia="1 1 1 2 2 2"/>'),
            r,
            ("inertia", "pole"),
        )
    )
    v.append(("no_inertial", "m.xml", mjcf(inertial=""), r, ("mass", "inertia", "pole")))
    v.append(
        (
            "pos_nan",
            "m.xml",
            mjcf(inertial='<inertial pos="0 0 nan" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/>'),
            r,
            ("pos", "nan", "pole"),
        )
    )
    for g, exp in (("0 0 nan", r), ("0 0 inf", r), ("0 0 1e300", e), ("0 0", r)):
        v.append((f"gravity_{g.replace(' ', '_')}", "m.xml", mjcf(gravity=g), exp, ("gravity",)))
    for ts, exp in (("0", r), ("-0.01", r), ("nan", r), ("1e-9", e), ("10", e)):
        v.append((f"timestep_{ts}", "m.xml", mjcf(timestep=ts), exp, ("timestep",)))
    for damp, exp in (("nan", r), ("-1", e), ("1e300", e)):
        v.append(
            (
                f"damping_{damp}",
                "m.xml",
                mjcf(joint=f'<joint name="hinge" type="hinge" axis="0 1 0" damping="{damp}"/>'),
                exp,
                ("damping", "hinge"),
            )
        )
    for gear, exp in (("0", r), ("nan", r)):
        v.append(
            (
                f"gear_{gear}",
                "m.xml",
                mjcf(actuator=f'<motor name="m" joint="hinge" gear="{gear}"/>'),
                exp,
                ("gear", "m", "actuator"),
            )
        )
    v.append(
        ("axis_zero", "m.xml", mjcf(joint='<joint name="hinge" type="hinge" axis="0 0 0"/>'), r, ("axis", "hinge"))
    )
    v.append(("no_actuator", "m.xml", mjcf(actuator=""), r, ("actuator",)))
    v.append(("no_joint", "m.xml", mjcf(joint="", actuator=""), r, ("joint", "actuator")))
    v.append(
        ("free_joint", "m.xml", mjcf(joint='<freejoint name="float"/>', actuator=""), r, ("free", "float", "actuator"))
    )
    v.append(
        (
            "free_joint_site_motor",
            "m.xml",
            mjcf(
                joint='<freejoint name="float"/>',
                inertial='<inertial pos="0 0 0" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/><site name="s"/>',
                actuator='<motor name="t" site="s" gear="0 0 1 0 0 0"/>',
            ),
            e,
            ("free", "float", "quaternion"),
        )
    )
    v.append(
        ("ball_joint", "m.xml", mjcf(joint='<joint name="b" type="ball"/>', actuator=""), r, ("ball", "b", "actuator"))
    )
    v.append(("slide_joint", "m.xml", mjcf(joint='<joint name="hinge" type="slide" axis="1 0 0"/>'), e, ("slide",)))
    v.append(
        (
            "position_actuator",
            "m.xml",
            mjcf(actuator='<position name="m" joint="hinge" kp="10"/>'),
            e,
            ("position", "m", "actuator"),
        )
    )
    v.append(
        (
            "velocity_actuator",
            "m.xml",
            mjcf(actuator='<velocity name="m" joint="hinge" kv="1"/>'),
            e,
            ("velocity", "m", "actuator"),
        )
    )
    v.append(
        (
            "joint_range",
            "m.xml",
            mjcf(joint='<joint name="hinge" type="hinge" axis="0 1 0" range="0.5 1" limited="true"/>'),
            e,
            ("range", "hinge", "x0"),
        )
    )
    v.append(
        (
            "frictionloss",
            "m.xml",
            mjcf(joint='<joint name="hinge" type="hinge" axis="0 1 0" frictionloss="0.1"/>'),
            e,
            ("frictionloss", "hinge"),
        )
    )
    v.append(
        (
            "tendon",
            "m.xml",
            mjcf(
                extra='<tendon><fixed name="t"><joint joint="hinge" coef="1"/></fixed></tendon>',
                actuator='<motor name="m" tendon="t"/>',
            ),
            e,
            ("tendon", "t"),
        )
    )
    v.append(
        (
            "equality",
            "m.xml",
            mjcf(
                extra_body=SECOND_BODY,
                extra='<equality><joint joint1="hinge" joint2="h2"/></equality>',
            ),
            e,
            ("equality",),
        )
    )
    v.append(
        (
            "keyframe_bad_length",
            "m.xml",
            mjcf(extra='<keyframe><key name="k" qpos="0 0 0"/></keyframe>'),
            r,
            ("key", "qpos"),
        )
    )
    v.append(("keyframe_ok", "m.xml", mjcf(extra='<keyframe><key name="k" qpos="0"/></keyframe>'), "ok", ()))
    v.append(("include_missing", "m.xml", mjcf(extra='<include file="nothere.xml"/>'), r, ("nothere.xml", "include")))
    v.append(
        (
            "mesh_missing",
            "m.xml",
            mjcf(extra='<asset><mesh name="me" file="nothere.stl"/></asset>'),
            r,
            ("nothere.stl", "mesh"),
        )
    )
    v.append(("malformed_xml", "m.xml", mjcf()[:-30], r, ("m.xml", "xml", "line")))
    v.append(("empty_file", "m.xml", "", r, ("m.xml", "empty", "xml")))
    v.append(("binary_garbage", "m.xml", b"\x00\x01\xff\xfegarbage", r, ("m.xml", "xml")))
    v.append(("not_mujoco_root", "m.xml", "<robot_not><a/></robot_not>", r, ("m.xml", "mujoco", "urdf", "root")))
    v.append(("bom", "m.xml", b"\xef\xbb\xbf" + mjcf().encode(), e, ("BOM",)))
    v.append(
        (
            "latin1_comment",
            "m.xml",
            mjcf().replace("<worldbody>", "<!-- caf\xe9 --><worldbody>").encode("latin-1"),
            e,
            ("utf-8", "encoding"),
        )
    )
    v.append(("ext_mjcf", "m.mjcf", mjcf(), "ok", ()))
    v.append(("ext_upper_XML", "M.XML", mjcf(), "ok", ()))
    v.append(("ext_none", "model", mjcf(), e, ("model", "extension")))
    v.append(("ext_txt", "m.txt", mjcf(), e, ("m.txt", "extension")))
    v.append(
        (
            "two_actuated",
            "m.xml",
            mjcf(
                extra_body=SECOND_BODY,
                actuator='<motor name="m" joint="hinge"/><motor name="m2" joint="h2"/>',
            ),
            e,
            (),
        )
    )
    # URDF
    v.append(("urdf_ok", "r.urdf", urdf(), "ok", ()))
    v.append(("urdf_as_xml", "r.xml", urdf(), "ok", ()))
    v.append(("urdf_upper_ext", "R.URDF", urdf(), "ok", ()))
    for mass, exp in (("0", r), ("-1", r), ("nan", r)):
        v.append(
            (
                f"urdf_mass_{mass}",
                "r.urdf",
                urdf(inertial1=U_DEFAULTS["inertial1"].replace('value="0.1"', f'value="{mass}"')),
                exp,
                ("mass", "l1"),
            )
        )
    v.append(
        (
            "urdf_inertia_not_pd",
            "r.urdf",
            urdf(inertial1=U_DEFAULTS["inertial1"].replace('ixx="1e-4"', 'ixx="1"').replace('ixy="0"', 'ixy="5"')),
            r,
            ("inertia", "l1"),
        )
    )
    v.append(
        (
            "urdf_inertia_negative",
            "r.urdf",
            urdf(inertial1=U_DEFAULTS["inertial1"].replace('iyy="1e-4"', 'iyy="-1"')),
            r,
            ("inertia", "l1"),
        )
    )
    v.append(("urdf_no_inertial", "r.urdf", urdf(inertial1=""), r, ("inertial", "mass", "l1")))
    v.append(("urdf_continuous", "r.urdf", urdf(jtype="continuous"), e, ("continuous",)))
    v.append(("urdf_prismatic", "r.urdf", urdf(jtype="prismatic"), e, ("prismatic",)))
    v.append(("urdf_fixed_only", "r.urdf", urdf(jtype="fixed"), r, ("joint", "actuat", "fixed")))
    v.append(("urdf_floating", "r.urdf", urdf(jtype="floating"), r, ("floating", "j1")))
    v.append(("urdf_planar", "r.urdf", urdf(jtype="planar"), r, ("planar", "j1")))
    v.append(
        (
            "urdf_friction",
            "r.urdf",
            urdf(jextra='<dynamics damping="0.01" friction="0.2"/>'),
            e,
            ("friction", "j1", "r.urdf"),
        )
    )
    v.append(
        (
            "urdf_mimic",
            "r.urdf",
            urdf(extra=MIMIC),
            e,
            ("mimic", "j2", "r.urdf"),
        )
    )
    v.append(("urdf_origin_nan", "r.urdf", urdf(origin="0 0 nan"), r, ("origin", "nan", "j1")))
    v.append(
        (
            "urdf_mesh_missing",
            "r.urdf",
            urdf(
                extra='<link name="vis"><visual><geometry><mesh filename="package://nothere/x.stl"/></geometry></visual></link>'
            ),
            e,
            ("mesh", "x.stl", "nothere"),
        )
    )
    v.append(("urdf_malformed", "r.urdf", urdf()[:-20], r, ("r.urdf", "xml", "line")))
    v.append(
        (
            "urdf_unknown_parent",
            "r.urdf",
            urdf().replace('<parent link="base"/>', '<parent link="nothere"/>'),
            r,
            ("nothere", "parent"),
        )
    )
    return v


def probes(configs: Path, tree: Path) -> list[Probe]:
    out: list[Probe] = []
    for name, fname, content, expect, needles in _variants():
        file_setup = write_text(fname, content)
        for cmd in ("linearize", "crosscheck"):
            out.append(
                Probe(
                    f"{CAT}/{name}/{cmd}",
                    CAT,
                    argv=[cmd, fname],
                    expect=expect,
                    needles=needles,
                    setup=file_setup,
                    timeout=60,
                )
            )
        scen = {
            "plant": {"type": "MjcfPlant", "model": fname},
            "controller": {"type": "LQR", "Q": [1.0, 1.0], "R": [1.0]},
            "engine": {"type": "mujoco"},
            "sim": {"duration": 1.0, "initial_state": [0.05, 0.0]},
        }
        two = write_text("s.toml", dump_toml(scen))

        def setup(wd: Path, file_setup=file_setup, two=two) -> None:
            file_setup(wd)
            two(wd)

        run_expect = "either" if expect == "ok" else expect  # the 2-state LQR does not fit every variant
        out.append(
            Probe(
                f"{CAT}/{name}/run",
                CAT,
                argv=["run", "s.toml"],
                expect=run_expect,
                needles=(*needles, "Q", "state", "x0", "initial_state") if expect != "refuse" else needles,
                setup=setup,
                timeout=60,
            )
        )
    # the shipped model files under their odd names
    furuta = (
        (tree / "assets" / "furuta_pendulum.xml").read_text()
        if (tree / "assets" / "furuta_pendulum.xml").exists()
        else ""
    )
    if furuta:
        for fname in ("f.mjcf", "F.XML", "f.Xml"):
            for cmd in ("linearize", "crosscheck"):
                out.append(
                    Probe(
                        f"{CAT}/furuta_{fname}/{cmd}",
                        CAT,
                        argv=[cmd, fname],
                        expect="ok",
                        setup=write_text(fname, furuta),
                    )
                )
        for tag, new in (("gravity", 'gravity="0 0 nan"'), ("timestep", 'timestep="nan"')):
            bad = (
                furuta.replace('gravity="0 0 -9.81"', new)
                if tag == "gravity"
                else furuta.replace('timestep="0.002"', new)
            )
            for cmd in ("linearize", "crosscheck"):
                out.append(
                    Probe(
                        f"{CAT}/furuta_{tag}_nan/{cmd}",
                        CAT,
                        argv=[cmd, "f.xml"],
                        expect="refuse",
                        needles=(tag,),
                        setup=write_text("f.xml", bad),
                    )
                )
    return out
