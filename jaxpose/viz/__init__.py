"""Layer 6, pictures: rerun logging and blueprints, OpenCV overlays and renderings."""

from ._overlay import draw_model as draw_model
from ._overlay import draw_points as draw_points
from ._overlay import overlay as overlay
from ._overlay import render as render
from ._overlay import render_bench as render_bench
from ._rerun import close_recording as close_recording
from ._rerun import log_experiment as log_experiment
from ._rerun import log_pointing as log_pointing
from ._rerun import log_solution as log_solution
from ._rerun import log_triplets as log_triplets
from ._rerun import rerun_blueprint as rerun_blueprint
from ._rerun import rerun_recording as rerun_recording
