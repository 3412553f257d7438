"""Layer 6, applications: the paper's bench and experiment, model database, recognition
hypothesis verification, recognition without correspondences and from keypoints,
click-to-3D pointing, the robot, camera calibration, mesh files (PLY, OBJ, ViSP's .cao);
tracking through video (what a camera sees of a model, rays cast onto it, a software
renderer for ground-truth sequences, the tracker, a clicked point followed and its
uncertainty).
"""

from ._bench import Bench as Bench
from ._bench import Scene as Scene
from ._bench import cross_prism as cross_prism
from ._bench import default_bench as default_bench
from ._bench import random_scene as random_scene
from ._calibration import Calibration as Calibration
from ._calibration import CalibrationStatus as CalibrationStatus
from ._calibration import LedPairs as LedPairs
from ._calibration import calibrate as calibrate
from ._calibration import calibrate_with_robot as calibrate_with_robot
from ._calibration import dlt as dlt
from ._calibration import led_joint_grid as led_joint_grid
from ._calibration import simulate_led_pairs as simulate_led_pairs
from ._detect import Detection as Detection
from ._detect import detect as detect
from ._mesh import read_ply as read_ply
from ._mesh import write_ply as write_ply
from ._mesh_formats import read_cao as read_cao
from ._mesh_formats import read_mesh as read_mesh
from ._mesh_formats import read_obj as read_obj
from ._models import chessboard as chessboard
from ._models import model_bench as model_bench
from ._models import model_database as model_database
from ._pointing import Faces as Faces
from ._pointing import Hit as Hit
from ._pointing import PointingStatus as PointingStatus
from ._pointing import face_normals as face_normals
from ._pointing import intersect_ray as intersect_ray
from ._pointing import pick as pick
from ._pointing import polyhedron_faces as polyhedron_faces
from ._polyhedron import Polyhedron as Polyhedron
from ._recognition import Hypothesis as Hypothesis
from ._recognition import Verdict as Verdict
from ._recognition import Verification as Verification
from ._recognition import acceptance_thresholds as acceptance_thresholds
from ._recognition import verify as verify
from ._recognition import verify_hypotheses as verify_hypotheses
from ._recognize import Recognition as Recognition
from ._recognize import recognize as recognize
from ._reinit import recognition_reinit as recognition_reinit
from ._render import face_textures as face_textures
from ._render import noise_texture as noise_texture
from ._render import render as render
from ._render import render_sequence as render_sequence
from ._render import smooth_trajectory as smooth_trajectory
from ._robot import JOINT_NAMES as JOINT_NAMES
from ._robot import JointCommand as JointCommand
from ._robot import Robot as Robot
from ._robot import RobotState as RobotState
from ._robot import RobotStatus as RobotStatus
from ._robot import default_robot as default_robot
from ._robot import forward_kinematics as forward_kinematics
from ._robot import inverse_kinematics as inverse_kinematics
from ._robot import joint_command as joint_command
from ._samples import SAMPLES as SAMPLES
from ._samples import sample_path as sample_path
from ._textured import TexturedPose as TexturedPose
from ._textured import locate_matches as locate_matches
from ._textured import locate_textured as locate_textured
from ._track import TrackedFrame as TrackedFrame
from ._track import track as track
from ._track_options import TrackOptions as TrackOptions
from ._track_refine import RefinedTrack as RefinedTrack
from ._track_refine import motion_sigmas as motion_sigmas
from ._track_refine import refine_track as refine_track
from ._track_solve import frame_covariance as frame_covariance
from ._track_target import Anchor as Anchor
from ._track_target import Target as Target
from ._track_target import anchor_click as anchor_click
from ._track_target import follow_anchor as follow_anchor
from ._track_target import follow_click as follow_click
from ._visibility import EdgeSamples as EdgeSamples
from ._visibility import MeshGeometry as MeshGeometry
from ._visibility import RayHits as RayHits
from ._visibility import cast_rays as cast_rays
from ._visibility import edge_samples as edge_samples
from ._visibility import face_mask as face_mask
from ._visibility import front_faces as front_faces
from ._visibility import mesh_geometry as mesh_geometry
