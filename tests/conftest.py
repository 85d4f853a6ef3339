import os

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


# A small URDF with prismatic, revolute and continuous joints (robot tests).
PRISMATIC_URDF = """<?xml version="1.0"?>
<robot name="slider_arm">
  <link name="rail"><collision><geometry><box size="1.0 0.1 0.05"/></geometry></collision></link>
  <joint name="slide" type="prismatic">
    <parent link="rail"/><child link="carriage"/>
    <origin xyz="0 0 0.05" rpy="0 0 0.3"/>
    <axis xyz="1 0 0"/>
    <limit lower="-0.4" upper="0.4" velocity="0.5" effort="10"/>
  </joint>
  <link name="carriage"><collision><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision></link>
  <joint name="turn" type="revolute">
    <parent link="carriage"/><child link="arm"/>
    <origin xyz="0 0 0.1" rpy="0.4 0 0"/>
    <axis xyz="0 0.6 0.8"/>
    <limit lower="-3" upper="3" velocity="1.0" effort="10"/>
  </joint>
  <link name="arm"><collision><origin xyz="0.15 0 0"/><geometry><box size="0.3 0.04 0.04"/></geometry></collision></link>
  <joint name="lift" type="prismatic">
    <parent link="arm"/><child link="hand"/>
    <origin xyz="0.3 0 0" rpy="0 0.5 0"/>
    <axis xyz="0 0 -1"/>
    <limit lower="0" upper="0.2" velocity="0.3" effort="10"/>
  </joint>
  <link name="hand"><collision><geometry><sphere radius="0.03"/></geometry></collision></link>
  <joint name="wrist" type="continuous">
    <parent link="hand"/><child link="tool"/>
    <origin xyz="0 0.02 0.05"/>
    <axis xyz="1 1 0"/>
  </joint>
  <link name="tool"/>
  <joint name="tip_fixed" type="fixed">
    <parent link="tool"/><child link="tip"/>
    <origin xyz="0 0 0.08" rpy="0.1 0.2 0.3"/>
  </joint>
  <link name="tip"/>
</robot>
"""


@pytest.fixture(scope="session")
def prismatic_urdf():
    return PRISMATIC_URDF
