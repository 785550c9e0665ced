"""The pure core: model, belief filter, uncertainty, structure checks, bounds, search.

Nothing under this package imports rclpy (a test enforces it).
"""

from .belief import ImpossibleObservation, predict, update
from .model import POMDP, ModelError, action_of_priority, priority_of

__all__ = [
           "POMDP",
           "ImpossibleObservation",
           "ModelError",
           "action_of_priority",
           "predict",
           "priority_of",
           "update",
]
