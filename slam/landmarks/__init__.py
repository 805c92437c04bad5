"""Recognised objects as landmarks in the pose graph.

A robot with a push-broom line laser (`sensor`) drives a simulated planar world with
known objects on the floor (`world`); the mapper segments object clusters from the
scans (`segmentation`), recognises them against a library of stripe descriptors
(`library`, the stripes paper's matcher from `loopclosure.stripes`), and adds each
recognised object as a landmark with robust range-bearing factors (`graph`); seeing a
recognised object again closes an object-level loop.  `experiment.run_landmarks`
maps one run with and without the landmarks; `evaluation.landmarks_benchmark`
scores it.
"""

from slam.landmarks.experiment import (
    ClusterRecord,
    LandmarkResult,
    LandmarkRunConfig,
    run_landmarks,
)
from slam.landmarks.graph import GraphConfig, LandmarkObservation, LandmarkSolution, solve
from slam.landmarks.library import (
    LibraryConfig,
    ObjectLibrary,
    Recognition,
    RecognitionConfig,
)
from slam.landmarks.segmentation import ObjectCluster, SegmentationConfig, segment
from slam.landmarks.sensor import PlacedObject, PushBroomLaser, cast, place_object
from slam.landmarks.world import LandmarkRun, WorldConfig, simulate_landmark_run

__all__ = [
    "ClusterRecord",
    "GraphConfig",
    "LandmarkObservation",
    "LandmarkResult",
    "LandmarkRun",
    "LandmarkRunConfig",
    "LandmarkSolution",
    "LibraryConfig",
    "ObjectCluster",
    "ObjectLibrary",
    "PlacedObject",
    "PushBroomLaser",
    "Recognition",
    "RecognitionConfig",
    "SegmentationConfig",
    "WorldConfig",
    "cast",
    "place_object",
    "run_landmarks",
    "segment",
    "simulate_landmark_run",
    "solve",
]
