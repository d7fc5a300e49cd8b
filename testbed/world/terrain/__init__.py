"""Terrains: the presets (flat, slope, step, rough), courses of segments and height maps.

Every terrain is a union of boxes (dartpy has no height-field binding and cannot build meshes from
arrays), and also answers analytic height h(x, y) and normal n(x, y) queries, which the tests check
against the DART shapes. `geometry` holds the boxes and the distance laws, `base` the Terrain class
and the registry, then one module per kind of ground.
"""

from testbed.world.terrain.base import (EDGE, ROUGH_PATCH, TERRAIN_STREAM, TERRAINS, Terrain, TerrainFeature,
                                        check_terrain_config, make_terrain)
from testbed.world.terrain.course import CourseTerrain
from testbed.world.terrain.geometry import (BASE_DEPTH, BLOCKS_AROUND, BOX, CANDIDATE_RULE, EVERY_BOX, NO_BOX, Boxes,
                                            axis_aligned_boxes, box_distance, box_distances, candidate_rule,
                                            candidates_by_rule, closest_distance, distances_to_boxes,
                                            signed_distance_to_boxes, sphere_contact_arrays, sphere_contacts)
from testbed.world.terrain.grid import GridTerrain
from testbed.world.terrain.heightmap import HeightmapTerrain
from testbed.world.terrain.presets import FlatTerrain, RoughTerrain, SlopeTerrain, StepTerrain

__all__ = ["BASE_DEPTH", "BLOCKS_AROUND", "BOX", "CANDIDATE_RULE", "EDGE", "EVERY_BOX", "NO_BOX", "ROUGH_PATCH", "TERRAINS",
           "TERRAIN_STREAM", "TerrainFeature",
           "Boxes", "CourseTerrain", "FlatTerrain", "GridTerrain", "HeightmapTerrain", "RoughTerrain", "SlopeTerrain",
           "StepTerrain", "Terrain", "axis_aligned_boxes", "box_distance", "box_distances", "candidate_rule",
           "candidates_by_rule", "check_terrain_config", "closest_distance", "distances_to_boxes", "make_terrain",
           "signed_distance_to_boxes", "sphere_contact_arrays", "sphere_contacts"]
