"""North finding on the host: heading solvers, denoising, procedures and the ``northfinder`` CLI.

Imports go one way: ``host`` uses ``driver``; it never imports ``firmware_sim`` except in the CLI
commands that embed the simulated instrument.
"""

from northfinder.host.errors import HostError

__all__ = ["HostError"]
