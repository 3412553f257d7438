"""Layer 8, the command line `jaxpose` (`reproduce`, `bench`, `solve`, `point`, `recognize`,
`warmup`) and its problem files.
"""

from ._main import build_parser as build_parser
from ._main import main as main
from ._main import run as run
