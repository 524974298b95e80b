"""The virtual printer: simulated time, motion, bed, contact physics, load-cell sensor,
nozzle, faults and named scenarios. See docs/virtual-printer.md."""

from tapcell.host.backend import MoveError, ProbingMoveResult, SampleBatch
from tapcell.sim.faults import FAULT_DEFAULTS, FaultError, McuResetError
from tapcell.sim.params import SimParamError, SimParams
from tapcell.sim.printer import VirtualPrinter
from tapcell.sim.scenarios import SCENARIOS

__all__ = ["FAULT_DEFAULTS", "FaultError", "McuResetError", "MoveError", "ProbingMoveResult", "SCENARIOS", "SampleBatch",
           "SimParamError", "SimParams", "VirtualPrinter"]
