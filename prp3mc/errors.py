"""Exception types raised by prp3mc.

Every error a user can cause derives from :class:`Prp3mcError`; the command
line turns these into a one-line message and a non-zero exit status.
"""

__all__ = [
    "Prp3mcError",
    "GeometryError",
    "UnknownPresetError",
    "InputFileError",
    "InfeasiblePoseError",
    "ConvergenceError",
    "BudgetError",
    "NoExactYieldError",
    "StudyError",
    "CampaignError",
    "AllocationError",
    "SpecError",
    "ResourceError",
    "ParameterError",
    "NonlinearityError",
    "MissingDependencyError",
    "OutputError",
    "OutputExistsError",
    "OutputBusyError",
    "FigureFormatError",
    "Prp3mcWarning",
    "IncompleteBudgetWarning",
    "LinearityWarning",
]


class Prp3mcError(Exception):
    """Base class of every error prp3mc raises on bad input."""


class GeometryError(Prp3mcError, ValueError):
    """A manipulator geometry is malformed (non-finite, unordered stroke...)."""


class UnknownPresetError(Prp3mcError, KeyError):
    """A preset name (geometry, budget, study) is not known."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class InputFileError(Prp3mcError, ValueError):
    """A TOML or CSV file is missing, unreadable or malformed."""


class InfeasiblePoseError(Prp3mcError, ValueError):
    """A pose leaves a stroke, has d_i <= 0, is near a singularity or is NaN."""


class ConvergenceError(Prp3mcError, RuntimeError):
    """A nonlinear solve (forward kinematics, perturbed chain) did not converge."""


class BudgetError(Prp3mcError, ValueError):
    """An error budget names an unknown input or an impossible law."""


class NoExactYieldError(BudgetError):
    """The exact yield cannot serve this budget (no density its series can sum, or too many classes to
    enumerate); Monte Carlo can (``prp3mc yield`` falls back on it)."""


class StudyError(Prp3mcError, ValueError):
    """A study file is malformed; the message names the line and the reason."""


class CampaignError(Prp3mcError, ValueError):
    """A measurement campaign is malformed; the message names row and column."""


class AllocationError(Prp3mcError, ValueError):
    """A tolerance-allocation problem is malformed (classes file, costs, specs)."""


class SpecError(Prp3mcError, ValueError):
    """A specification of the pose error (a tolerance on the position or the orientation) is malformed."""


class ResourceError(Prp3mcError, ValueError):
    """A request needs more memory than this machine has available."""


class ParameterError(Prp3mcError, ValueError):
    """An analysis was asked for something outside its domain: a sample count, a level or percentile, an
    output, statistic or method it does not know, results that do not belong together."""


class NonlinearityError(Prp3mcError, ValueError):
    """The exact chain cannot be evaluated at an estimate (its closure does not converge, or is singular), or the
    discrepancy workflow's relinearisation does not settle: what trips its linearity guard."""


class MissingDependencyError(Prp3mcError, ImportError):
    """An optional dependency is not installed; :attr:`install` is the pip line that brings it."""

    def __init__(self, package: str, install: str, needed_for: str = ""):
        need = f"{needed_for} needs {package}, which is not installed" if needed_for else f"{package} is not installed"
        super().__init__(f"{need}: {install}", name=package)
        self.install = install


class OutputError(Prp3mcError, OSError):
    """An output folder cannot be created, claimed or written."""


class OutputExistsError(OutputError, FileExistsError):
    """The output folder exists and ``force`` was not given."""


class OutputBusyError(OutputError):
    """Another live run holds the claim on the output folder."""


class FigureFormatError(Prp3mcError, ValueError):
    """A figure format that reports cannot write."""


class Prp3mcWarning(UserWarning):
    """Base of the warnings prp3mc gives (an analysis runs, but a result needs care)."""


class IncompleteBudgetWarning(Prp3mcWarning):
    """A budget leaves out inputs that it names for other legs."""


class LinearityWarning(Prp3mcWarning):
    """The linear error model departs from the exact chain by more than its tolerance."""
