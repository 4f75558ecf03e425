"""The one training loop shared by every method and evaluator (checkpoints, resume, schedules)."""

from repro.train.loop import TrainResult, train
from repro.train.schedules import linear_ramp
from repro.train.validation import holdout

__all__ = ["train", "TrainResult", "linear_ramp", "holdout"]
