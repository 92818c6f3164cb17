"""KTH SLAM Summer School 2002 datasets (ACFR ute): loaders, beacon extraction, bag converter.

Only numpy/scipy are needed here (``beacon_node`` needs rclpy, ``convert`` needs
rosbags; both are imported lazily by their own modules).
"""
from .beacons import Beacons, extract_beacons, observation_columns
from .datasets import (VEHICLE, CarPark, GpsTrack, LaserScans, OdometryStream, TreeDetections,
                       Vehicle, VictoriaPark, default_data_dir, load, load_car_park,
                       load_tree_detections, load_victoria_park)

__all__ = [
    "Beacons", "extract_beacons", "observation_columns",
    "VEHICLE", "CarPark", "GpsTrack", "LaserScans", "OdometryStream", "TreeDetections",
    "Vehicle", "VictoriaPark", "default_data_dir", "load", "load_car_park",
    "load_tree_detections", "load_victoria_park",
]
