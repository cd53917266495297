"""An MJCF finger written the way MyoSuite writes its tendon finger, with as many tendons as a
test asks for.

Every body sits at the world origin and its joint at ``pos=`` (so a picture drawn from body
frames puts every joint at the origin), the first joint's tendons wrap a sphere, the second
joint's a cylinder pin, and one tendon splits at two pulleys into three branches (the
extensor hood of a finger). Three joints: two flexing about y, one turning about z.
"""

from __future__ import annotations

from pathlib import Path

JOINTS = ("knuckle_flexion", "middle_flexion", "tip_sideways")


def offset_finger_xml(pairs_per_joint: int) -> str:
    """MJCF text: ``pairs_per_joint`` flexor/extensor pairs on each joint, plus the pulley
    tendon (2 * 3 * pairs + 1 tendons)."""
    sites = {"world": [], "proximal": [], "middle": [], "distal": []}
    tendons = []
    for k in range(pairs_per_joint):
        off = -0.008 + 0.016 * k / max(pairs_per_joint - 1, 1)
        for side, dz in (("flex", -0.01), ("ext", 0.01)):
            name = f"j1_{side}{k}"
            sites["world"].append(f'<site name="{name}_a" pos="-0.03 {off:.4f} {0.3 + dz}"/>')
            sites["proximal"].append(f'<site name="{name}_b" pos="0.04 {off:.4f} {0.3 + dz}"/>')
            tendons.append(f'<spatial name="{name}"><site site="{name}_a"/>'
                           f'<geom geom="ball"/><site site="{name}_b"/></spatial>')
            name = f"j2_{side}{k}"
            sites["proximal"].append(f'<site name="{name}_a" pos="0.06 {off:.4f} {0.3 + dz}"/>')
            sites["middle"].append(f'<site name="{name}_b" pos="0.14 {off:.4f} {0.3 + dz}"/>')
            tendons.append(f'<spatial name="{name}"><site site="{name}_a"/>'
                           f'<site site="{name}_b"/></spatial>')
        for side, dy in (("left", 0.01), ("right", -0.01)):
            name = f"j3_{side}{k}"
            sites["middle"].append(f'<site name="{name}_a" pos="0.16 {dy} {0.3 + off:.4f}"/>')
            sites["distal"].append(f'<site name="{name}_b" pos="0.24 {dy} {0.3 + off:.4f}"/>')
            tendons.append(f'<spatial name="{name}"><site site="{name}_a"/>'
                           f'<site site="{name}_b"/></spatial>')
    sites["world"].append('<site name="hood_a" pos="-0.03 0 0.33"/>')
    sites["proximal"] += ['<site name="hood_b" pos="0.04 0 0.32"/>',
                          '<site name="hood_c" pos="0.06 0 0.305"/>',
                          '<site name="pin_side" pos="0.1 0 0.33"/>']
    sites["middle"] += ['<site name="hood_d" pos="0.13 0 0.306"/>',
                        '<site name="hood_e" pos="0.15 0.004 0.306"/>']
    # the hood: over the knuckle, then two slips over the middle joint's pin (MuJoCo halves
    # each slip's length: a pulley with divisor 2 before each)
    tendons.append('<spatial name="hood"><site site="hood_a"/><site site="hood_b"/>'
                   '<pulley divisor="2"/><site site="hood_c"/>'
                   '<geom geom="pin" sidesite="pin_side"/><site site="hood_d"/>'
                   '<pulley divisor="2"/><site site="hood_c"/>'
                   '<geom geom="pin" sidesite="pin_side"/><site site="hood_e"/></spatial>')
    body = "\n".join
    return f"""<mujoco model="offset-finger">
  <compiler angle="degree"/>
  <default><geom contype="0" conaffinity="0" size="0.01"/><site size="0.002"/></default>
  <worldbody>
    {body(sites["world"])}
    <body name="proximal">
      <joint name="{JOINTS[0]}" type="hinge" pos="0 0 0.3" axis="0 1 0" range="-30 60"/>
      <geom type="capsule" fromto="0 0 0.3 0.1 0 0.3" size="0.006" mass="0.02"/>
      <geom name="ball" type="sphere" pos="0 0 0.3" size="0.015" mass="0.001"/>
      {body(sites["proximal"])}
      <body name="middle">
        <joint name="{JOINTS[1]}" type="hinge" pos="0.1 0 0.3" axis="0 1 0" range="-10 80"/>
        <geom type="capsule" fromto="0.1 0 0.3 0.2 0 0.3" size="0.005" mass="0.01"/>
        <geom name="pin" type="cylinder" fromto="0.1 0.005 0.3 0.1 -0.005 0.3" size="0.012"
              mass="0.001"/>
        {body(sites["middle"])}
        <body name="distal">
          <joint name="{JOINTS[2]}" type="hinge" pos="0.2 0 0.3" axis="0 0 1" range="-20 20"/>
          <geom type="capsule" fromto="0.2 0 0.3 0.26 0 0.3" size="0.004" mass="0.005"/>
          {body(sites["distal"])}
        </body>
      </body>
    </body>
  </worldbody>
  <tendon>
    {body(tendons)}
  </tendon>
</mujoco>
"""


def write_offset_finger(folder: Path, pairs_per_joint: int) -> Path:
    """The finger as ``folder/offset_finger_<n>.xml``."""
    path = folder / f"offset_finger_{pairs_per_joint}.xml"
    path.write_text(offset_finger_xml(pairs_per_joint))
    return path
