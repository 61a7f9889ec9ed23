"""What the bench scripts share: tables, SIMD levels, interleaved children, the e2e tables, the anchor's
frames, a free ROS domain id. Not scripts: bench/README.md lists those."""
