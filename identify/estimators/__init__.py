"""Time-domain maximum-likelihood estimators: output error and filter error."""

from identify.estimators.dynamics import Record, StateSpaceModel, linearize, simulate
from identify.estimators.outputerror import OutputError
from identify.estimators.results import TimeDomainResults

__all__ = ["OutputError", "Record", "StateSpaceModel", "TimeDomainResults", "linearize", "simulate"]
