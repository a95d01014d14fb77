"""Scenes: the parameter table, typed scene values, validation and loading, sampling, meshes."""
from .description import (PARAMETERS, Param, Scene, apply_overrides, list_scenes, load_scene,
                          parameter_table_markdown, scene_from_dict)

__all__ = ["PARAMETERS", "Param", "Scene", "apply_overrides", "list_scenes", "load_scene",
           "parameter_table_markdown", "scene_from_dict"]
