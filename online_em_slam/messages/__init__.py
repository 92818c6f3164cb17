"""Message encodings shared by the node and the bag tools: PointCloud2 columns, quaternions."""
