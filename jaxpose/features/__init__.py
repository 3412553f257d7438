"""Layer 5, image features: from a photograph to what the pose methods take. Line
segments and their junctions (the paper's vertices) for polyhedral models; keypoints
matched against a textured model for textured objects; the files that describe models
and cameras (PLY meshes, OpenCV's textured-model and camera YAML); for tracking, frame
sources (video, folder, camera), moving edges and KLT points. Plain numpy and OpenCV:
nothing here is traced.
"""

from ._files import read_camera as read_camera
from ._files import write_camera as write_camera
from ._keypoints import Matches as Matches
from ._keypoints import TexturedModel as TexturedModel
from ._keypoints import match_keypoints as match_keypoints
from ._keypoints import read_textured_model as read_textured_model
from ._klt import Tracks as Tracks
from ._klt import detect_corners as detect_corners
from ._klt import track_points as track_points
from ._moving_edges import EdgeMatches as EdgeMatches
from ._moving_edges import moving_edges as moving_edges
from ._segments import Segments as Segments
from ._segments import chain_segments as chain_segments
from ._segments import detect_segments as detect_segments
from ._segments import edge_distance as edge_distance
from ._segments import oriented_edge_distance as oriented_edge_distance
from ._vertices import Primitives as Primitives
from ._vertices import Vertices as Vertices
from ._vertices import find_vertices as find_vertices
from ._vertices import image_primitives as image_primitives
from ._vertices import vertex_links as vertex_links
from ._video import IMAGE_SUFFIXES as IMAGE_SUFFIXES
from ._video import Frames as Frames
from ._video import open_frames as open_frames
