"""Robots: each builds its MJCF part, names its joints, actuators and sites, gives its home
state and turns an action into actuator (and mocap) targets (``base.Robot``). ``make_robot``
builds the one ``RobotConfig.kind`` names; the SIH hand (``sih``) is the part both carry."""

from __future__ import annotations

from trainer.config import ROBOTS as ROBOT_NAMES
from trainer.config import RobotConfig
from trainer.robots.base import Robot
from trainer.robots.floating import FloatingHand
from trainer.robots.ur5e import UR5eRobot

ROBOTS: dict[str, type[Robot]] = {"ur5e": UR5eRobot, "floating": FloatingHand}
assert set(ROBOTS) == set(ROBOT_NAMES), "trainer.config.ROBOTS must list every robot"


def make_robot(cfg: RobotConfig) -> Robot:
    """The robot ``cfg.kind`` names."""
    return ROBOTS[cfg.kind](cfg)


__all__ = ["ROBOTS", "FloatingHand", "Robot", "UR5eRobot", "make_robot"]
