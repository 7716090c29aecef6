"""MeshSet conversion, the plugin-style filter registry, and the pcprep command line."""
