"""Tactile descriptor and classifiers: triangles from contacts, 3-D histograms, distances,
classifiers p(y|h), and the on-disk training dataset."""
