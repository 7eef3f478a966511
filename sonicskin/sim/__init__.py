"""The simulated rig: a modal model of a robot link's acoustic channel, fingers, noise, scenarios."""

from .channel import MATERIALS, ChannelModel, Geometry, Material
from .scenario import Scenario, Timeline, build_timeline
from .simulator import Simulator

__all__ = ["MATERIALS", "ChannelModel", "Geometry", "Material", "Scenario", "Timeline", "build_timeline", "Simulator"]
