"""Geometry: triangle meshes and solid primitives with exact signed distances."""

from depthguard.geometry.mesh import Mesh, as_mesh, load_mesh, merge_meshes
from depthguard.geometry.primitives import Box, Capsule, Cylinder, Primitive, Sphere, sdf_union

__all__ = ["Mesh", "as_mesh", "load_mesh", "merge_meshes", "Box", "Capsule", "Cylinder",
           "Primitive", "Sphere", "sdf_union"]
