"""What the grasps say: the paper's descriptor and classifiers (triangles from contacts, 3-D
histograms, p(y|h)), the grasp likelihood over the training grasps, the class x placement
belief on the meshes (the default), the sensor-fault checks, and the training dataset."""
