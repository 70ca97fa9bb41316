"""File formats: the only package that reads or writes files."""

from kincal.io.models import (
    builtin_names,
    dump_robot,
    load_builtin,
    load_robot,
    parse_robot,
    read_robot,
    robot_to_dict,
    save_robot,
    select_arm,
)
from kincal.io.urdf import from_urdf, to_urdf

__all__ = [
    "builtin_names",
    "dump_robot",
    "from_urdf",
    "load_builtin",
    "load_robot",
    "parse_robot",
    "read_robot",
    "robot_to_dict",
    "save_robot",
    "select_arm",
    "to_urdf",
]
