"""The landmark map: the landmark table and the map file."""
