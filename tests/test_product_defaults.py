"""The product's defaults are defined once (issue 28): the library's functions default to
:class:`~depthguard.config.MonitorConfig`'s values, so a caller that leaves a setting out gets
what the product runs with. Truth: the signatures themselves (``inspect``), against the
config model's field defaults."""

from __future__ import annotations

import inspect

import pytest

from depthguard.config import MonitorConfig
from depthguard.distance.api import DistanceWorkspace, depth_space_distance
from depthguard.distance.cartesian import CartesianBaseline
from depthguard.distance.reference import obstacle_start_depth_numpy


@pytest.mark.parametrize("fn", [DistanceWorkspace.set_depth, depth_space_distance, CartesianBaseline.set_depth,
                                obstacle_start_depth_numpy], ids=lambda f: f.__qualname__)
def test_self_removal_offset_is_the_products(fn):
    default = inspect.signature(fn).parameters["robot_offset"].default
    assert default == MonitorConfig().robot_offset == 0.08          # R9 (config.PRODUCT_ROBOT_OFFSET)


@pytest.mark.parametrize("fn", [DistanceWorkspace.query, depth_space_distance], ids=lambda f: f.__qualname__)
def test_radius_of_surveillance_is_the_products(fn):
    assert inspect.signature(fn).parameters["rho"].default == MonitorConfig().rho
