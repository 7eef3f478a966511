"""ONNX export of the network and the SVM baseline (the learned-model issue fills this package)."""
