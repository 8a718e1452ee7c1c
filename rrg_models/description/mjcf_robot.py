"""MJCF of the robot: the Barrett WAM (7 DOF) carrying a BarrettHand BH8-282 with Nano17 fingertips.

Built from the shared models, so physics and the planning core agree by construction:

* the WAM body tree from ``config.WAM``'s DH table (body i sits at DH frame i-1 and turns about
  its local z by q_i), Barrett's link mass properties ``config.WAM_LINKS`` and rotor inertias
  ``config.WAM_ARMATURE``, joint position servos (libbarrett's stiffness, critically damped,
  ``config.PHYSICS``) with gravity compensation (``gravcomp``), the hand mounted at
  ``rrg_models.wam.HAND_MOUNT``;
* the hand from ``rrg_models.hand.hand_tree()``: spread joints of fingers 1 and 2 coupled by an
  equality, torque-limited proximal position servos, distal joints coupled to the proximal at
  ``HAND.distal_coupling``, a ``touch`` sensor on a site around each of the 7 pads, and a Nano17
  ``force`` + ``torque`` sensor at the base of each welded fingertip body.

Layout follows mujoco_menagerie: ``<default>`` classes and a robot file that a scene includes.
Robot geoms (contype 1, conaffinity 2) never touch each other, only the table and the object
(collision bits in rrg_sim.physics.scene).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np

from rrg_models.config import HAND, PHYSICS, SENSOR_NAMES, WAM, WAM_ARMATURE, WAM_LINKS
from rrg_models.description.mjcf import full_inertia_in, pose_attrs, sub, to_xml
from rrg_models.hand import FINGERS, BodySpec, GeomSpec, hand_tree
from rrg_models.objects.primitives import primitive_volume
from rrg_models.wam import HAND_MOUNT

ROBOT_FILE = "wam_barretthand.xml"
ARM_JOINTS = tuple(f"wam/j{i}" for i in range(1, 8))
FINGER_JOINTS = tuple(f"bh/f{i}_prox" for i in FINGERS)
SPREAD_JOINT = "bh/f1_spread"
#: The hand's joints: spread of fingers 1 and 2, proximal 1-3, distal 1-3.
HAND_JOINTS = (
    SPREAD_JOINT,
    "bh/f2_spread",
    *FINGER_JOINTS,
    *(f"bh/f{i}_dist" for i in FINGERS),
)
PALM_BODY = "bh/palm"
TIP_BODIES = tuple(f"bh/f{i}_tip" for i in FINGERS)
#: Actuator order: 7 arm servos, the spread servo, 3 proximal servos.
ARM_ACTUATORS = tuple(f"wam/a{i}" for i in range(1, 8))
SPREAD_ACTUATOR = "bh/spread"
FINGER_ACTUATORS = tuple(f"bh/f{i}" for i in FINGERS)
#: Sensor names: touch pads in config.SENSOR_NAMES order, then Nano17 force and torque per tip.
PAD_TOUCH = tuple(f"bh/{name}_touch" for name in SENSOR_NAMES[:7])
TIP_FORCE = tuple(f"bh/tip{i}_force" for i in FINGERS)
TIP_TORQUE = tuple(f"bh/tip{i}_torque" for i in FINGERS)

ROBOT_CONTYPE, ROBOT_CONAFFINITY = 1, 2
#: Touch sites reach this far beyond each pad geom [m] so contact points on its surface count.
TOUCH_SITE_MARGIN = 0.002
#: Mass of each finger base (spread knuckle) [kg] (chosen: the BH8-282's 1.18 kg total less the
#: palm, links and Nano17s of config, shared by the three knuckle assemblies).
KNUCKLE_MASS = 0.07


def dh_local(i: int) -> np.ndarray:
    """Fixed part Tz(d) Tx(a) Rx(α) of joint i's DH transform (0-based): body i → DH frame i."""
    alpha, a, d = WAM.dh[i]
    ca, sa = math.cos(alpha), math.sin(alpha)
    return np.array(
        [[1.0, 0.0, 0.0, a], [0.0, ca, -sa, 0.0], [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]]
    )


def _inertia_frame(i: int) -> np.ndarray:
    """Frame of Barrett's mass data for link i in body i: DH frame i, except link 7 whose data
    are given at the tool plate with α = 0 (z along the roll axis)."""
    if i == 6:
        T = np.eye(4)
        T[2, 3] = WAM.dh[6][2]
        return T
    return dh_local(i)


#: Colours of the arm's and the hand's geoms (RGBA).
ARM_RGBA = "0.78 0.78 0.8 1"
HAND_RGBA = "0.25 0.25 0.28 1"


def base_geom() -> dict:
    """The WAM base's collision box in its body frame (chosen: the base housing under J1)."""
    half_height = (WAM.base_height - 0.2) / 2
    return dict(type="box", size=(0.12, 0.12, half_height), pos=(-0.04, 0, half_height))


def _arm_geoms(i: int) -> list[dict]:
    """Collision shapes of WAM link i (0-based) in its body frame (chosen: the WAM's outer
    shells; the upper arm at WAM.link_radius, the planning core's table-clearance radius)."""
    r = WAM.link_radius
    upper, fore = WAM.dh[2][2], WAM.dh[4][2]
    elbow = WAM.dh[2][1]
    flange = WAM.dh[6][2] + WAM.hand_mount
    return [
        [dict(type="cylinder", size=(0.09, 0.12), pos=(0, 0, -0.1))],  # shoulder yaw housing
        [dict(type="sphere", size=(0.09,))],  # shoulder pitch
        [dict(type="capsule", fromto=(0, 0, 0.12, 0, 0, upper - 0.08), size=(r,))],  # upper arm
        [
            dict(type="sphere", size=(r,)),  # elbow, then the forearm along -y from x = -a
            dict(
                type="capsule", fromto=(-elbow, -0.06, 0, -elbow, -(fore - 0.08), 0), size=(0.045,)
            ),
        ],
        [dict(type="sphere", size=(0.05,))],  # wrist yaw
        [dict(type="sphere", size=(0.045,))],  # wrist pitch
        [
            dict(type="cylinder", size=(0.04, flange / 2), pos=(0, 0, flange / 2))
        ],  # wrist roll to the hand
    ][i]


def _defaults(root: ET.Element) -> None:
    d = sub(root, "default")
    wam = sub(d, "default", **{"class": "wam"})
    sub(wam, "joint", type="hinge", axis="0 0 1")
    sub(
        wam,
        "geom",
        contype=ROBOT_CONTYPE,
        conaffinity=ROBOT_CONAFFINITY,
        group=1,
        rgba=ARM_RGBA,
        friction=f"{PHYSICS.hand_friction} 0.005 0.0001",
    )
    sub(wam, "position", ctrllimited="false")
    bh = sub(d, "default", **{"class": "bhand"})
    sub(bh, "joint", type="hinge", armature=PHYSICS.hand_armature)
    sub(
        bh,
        "geom",
        contype=ROBOT_CONTYPE,
        conaffinity=ROBOT_CONAFFINITY,
        group=1,
        condim=4,
        friction=f"{PHYSICS.hand_friction} 0.005 0.0001",
        rgba=HAND_RGBA,
    )
    sub(bh, "site", group=4, rgba="0.9 0.2 0.2 0.3")
    pad = sub(bh, "default", **{"class": "pad"})
    sub(pad, "geom", rgba="0.1 0.1 0.1 1")
    tip = sub(bh, "default", **{"class": "nano17"})
    sub(tip, "geom", rgba="0.75 0.75 0.78 1")
    sub(tip, "site", type="sphere", size=0.002)
    finger = sub(bh, "default", **{"class": "finger"})
    sub(
        finger,
        "position",
        kp=PHYSICS.finger_kp,
        kv=PHYSICS.finger_kv,
        forcerange=f"{-HAND.close_torque} {HAND.close_torque}",
    )


def _arm(worldbody: ET.Element) -> ET.Element:
    """WAM base and links 1-7 under worldbody; returns link 7's body (the flange carrier)."""
    base = sub(worldbody, "body", name="wam/base", childclass="wam")
    sub(base, "geom", name="wam/base", **base_geom())
    parent, T = base, np.eye(4)
    T[2, 3] = WAM.base_height
    for i in range(7):
        body = sub(parent, "body", name=f"wam/link{i + 1}", gravcomp=1, **pose_attrs(T))
        link = WAM_LINKS[i]
        F = _inertia_frame(i)
        sub(
            body,
            "inertial",
            pos=(F @ np.r_[link.com, 1.0])[:3],
            mass=link.mass,
            fullinertia=full_inertia_in(F, link.inertia),
        )
        sub(
            body,
            "joint",
            name=ARM_JOINTS[i],
            range=(WAM.lower[i], WAM.upper[i]),
            armature=WAM_ARMATURE[i],
        )
        for k, g in enumerate(_arm_geoms(i)):
            sub(body, "geom", name=f"wam/link{i + 1}_{k}", **g)
        parent, T = body, dh_local(i)
    return parent


def _geom(body: ET.Element, g: GeomSpec, density: float) -> None:
    cls = "nano17" if g.name.endswith("_tip") else ("pad" if g.sensor >= 0 else None)
    sub(
        body,
        "geom",
        name=f"bh/{g.name}",
        type=g.kind,
        size=g.size,
        pos=g.pos,
        quat=g.quat,
        density=density,
        **({"class": cls} if cls else {}),
    )


def _body_mass(b: BodySpec) -> float:
    if b.name == "palm":
        return HAND.palm_mass
    if b.name.endswith("_tip"):
        return PHYSICS.nano17_mass
    if b.name.endswith(("_prox", "_dist")):
        return HAND.finger_link_mass
    return KNUCKLE_MASS


def _touch_site(body: ET.Element, g: GeomSpec) -> None:
    """A site enclosing pad geom g (touch sensors sum contact forces inside a site's volume)."""
    size = [s + TOUCH_SITE_MARGIN for s in g.size]
    sub(
        body,
        "site",
        name=f"bh/{SENSOR_NAMES[g.sensor]}_pad",
        type=g.kind,
        size=size,
        pos=g.pos,
        quat=g.quat,
    )


def _hand(flange: ET.Element) -> None:
    """The BarrettHand tree from rrg_models.hand, mounted on the WAM flange."""
    bodies: dict[str | None, ET.Element] = {}
    for b in hand_tree():
        parent = flange if b.parent is None else bodies[b.parent]
        attrs = pose_attrs(HAND_MOUNT) if b.parent is None else {"pos": b.pos, "quat": b.quat}
        extra = {"childclass": "bhand"} if b.parent is None else {}
        el = sub(parent, "body", name=f"bh/{b.name}", gravcomp=1, **attrs, **extra)
        bodies[b.name] = el
        if b.geoms:
            massive = [
                g for g in b.geoms if not (b.name == "palm" and g.sensor >= 0)
            ]  # pad: a skin
            density = _body_mass(b) / sum(primitive_volume(g.kind, g.size) for g in massive)
            for g in b.geoms:
                _geom(el, g, density if g in massive else 0.0)
                if 0 <= g.sensor < 7:
                    _touch_site(el, g)
        else:
            m, r = _body_mass(b), 0.02  # knuckle housing as a 2 cm sphere
            sub(el, "inertial", pos=(0, 0, 0), mass=m, diaginertia=[0.4 * m * r * r] * 3)
        if b.joint is not None:
            sub(el, "joint", name=f"bh/{b.joint.name}", axis=b.joint.axis, range=b.joint.range)
        if b.name.endswith("_tip"):
            sub(el, "site", name=f"bh/{b.name}_ft", **{"class": "nano17"})


def _coupling(root: ET.Element) -> None:
    eq = sub(root, "equality")
    sub(
        eq,
        "joint",
        name="bh/spread_coupling",
        joint1="bh/f2_spread",
        joint2=SPREAD_JOINT,
        polycoef="0 1 0 0 0",
    )
    for b in hand_tree():
        if b.joint is not None and b.joint.coupled_to is not None:
            driver, ratio = b.joint.coupled_to
            sub(
                eq,
                "joint",
                name=f"bh/{b.joint.name}_coupling",
                joint1=f"bh/{b.joint.name}",
                joint2=f"bh/{driver}",
                polycoef=f"0 {ratio:.9g} 0 0 0",
            )


def _actuators(root: ET.Element) -> None:
    act = sub(root, "actuator")
    for i in range(7):
        sub(
            act,
            "position",
            name=ARM_ACTUATORS[i],
            joint=ARM_JOINTS[i],
            kp=PHYSICS.arm_kp[i],
            kv=PHYSICS.arm_kv[i],
            **{"class": "wam"},
        )
    sub(
        act,
        "position",
        name=SPREAD_ACTUATOR,
        joint=SPREAD_JOINT,
        kp=PHYSICS.spread_kp,
        kv=PHYSICS.spread_kv,
        ctrlrange=HAND.spread_range,
        **{"class": "bhand"},
    )
    for name, joint in zip(FINGER_ACTUATORS, FINGER_JOINTS):
        sub(
            act,
            "position",
            name=name,
            joint=joint,
            ctrlrange=HAND.proximal_range,
            **{"class": "finger"},
        )


def _sensors(root: ET.Element) -> None:
    sens = sub(root, "sensor")
    for name, sensor in zip(PAD_TOUCH, SENSOR_NAMES[:7]):
        sub(sens, "touch", name=name, site=f"bh/{sensor}_pad")
    for i, force, torque in zip(FINGERS, TIP_FORCE, TIP_TORQUE):
        sub(sens, "force", name=force, site=f"bh/f{i}_tip_ft")
        sub(sens, "torque", name=torque, site=f"bh/f{i}_tip_ft")


def robot_xml() -> str:
    """The robot MJCF (a complete ``<mujoco>`` document, included by the scene)."""
    root = ET.Element("mujoco", model="wam_barretthand")
    sub(root, "compiler", angle="radian", autolimits="true")
    # Elliptic friction cones with impratio 10: MuJoCo's recommended setting for grasping.
    sub(
        root,
        "option",
        timestep=PHYSICS.timestep,
        integrator="implicitfast",
        cone="elliptic",
        impratio=10,
    )
    _defaults(root)
    flange = _arm(sub(root, "worldbody"))
    _hand(flange)
    _coupling(root)
    _actuators(root)
    _sensors(root)
    return to_xml(root)
