"""The run assembly moved to :mod:`sonicskin.session` (a single link is an arm of one there).

Only ``cli/models.py`` (``arm_file_of``) and ``benchmarks/bench_arm.py`` (``open_arm``) still import these names from
here; once they import them from :mod:`sonicskin.session`, this module goes.
"""

from .session import arm_file_of
from .session import open_run as open_arm

__all__ = ["arm_file_of", "open_arm"]
