"""Baseline runners (MeshLab, CGAL, classic detectors), datasets and benchmark harness."""
