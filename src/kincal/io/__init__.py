"""File formats: the only package that reads or writes files."""

from kincal.io.models import dump_robot, load_robot, parse_robot, read_robot, robot_to_dict, save_robot, select_arm

__all__ = ["dump_robot", "load_robot", "parse_robot", "read_robot", "robot_to_dict", "save_robot", "select_arm"]
