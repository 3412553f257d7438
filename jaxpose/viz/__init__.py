"""Layer 7, pictures: rerun logging and blueprints, OpenCV overlays and renderings,
matplotlib figures."""

from ._figures import write_figures as write_figures
from ._overlay import draw_model as draw_model
from ._overlay import draw_points as draw_points
from ._overlay import overlay as overlay
from ._overlay import render as render
from ._overlay import render_bench as render_bench
from ._rerun_experiment import log_experiment as log_experiment
from ._rerun_layout import rerun_blueprint as rerun_blueprint
from ._rerun_pointing import log_pointing as log_pointing
from ._rerun_recognition import log_recognition as log_recognition
from ._rerun_recognition import recognition_blueprint as recognition_blueprint
from ._rerun_recording import close_recording as close_recording
from ._rerun_recording import rerun_recording as rerun_recording
from ._rerun_solution import log_solution as log_solution
from ._rerun_solution import log_triplets as log_triplets
from ._scenes import RenderedScene as RenderedScene
from ._scenes import rendered_scene as rendered_scene
from ._tracking import draw_target as draw_target
from ._tracking import draw_tracked as draw_tracked
from ._tracking import log_track_camera as log_track_camera
from ._tracking import log_tracked_frame as log_tracked_frame
from ._tracking import track_blueprint as track_blueprint
