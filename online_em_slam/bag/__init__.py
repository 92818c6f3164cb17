"""Bags: reading and writing (rosbags), replay over DDS, recording, a topic tool."""
