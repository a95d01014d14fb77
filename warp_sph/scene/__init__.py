"""Scenes: the parameter table, typed values, validation and loading, sampling and meshes.

    parameters.py   every key once: type, unit, default, range (methods add their sections)
    types.py        the dataclasses generated from those rows; ``Scene``
    validate.py     dict -> Scene or a one-line SceneError
    kinematic.py    [[bodies]] kinematic = true turned into animated obstacles
    load.py         built-in names and TOML files, ``--set`` overrides
    sampling.py     fluid lattice, wall and obstacle particles
    meshes.py       triangle meshes: loading, surface sampling, inside test
"""
from .load import apply_overrides, list_scenes, load_scene, parse_override_value, scene_from_dict
from .parameters import REQUIRED, Param, all_parameters, parameter_table_markdown
from .types import Container, FluidBlock, Material, Obstacle, OutputParams, Scene, TimeParams

__all__ = ["REQUIRED", "Container", "FluidBlock", "Material", "Obstacle", "OutputParams", "Param", "Scene",
           "TimeParams", "all_parameters", "apply_overrides", "list_scenes", "load_scene", "parameter_table_markdown",
           "parse_override_value", "scene_from_dict"]
