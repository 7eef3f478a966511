"""ONNX export of the network and the SVM baseline into one deployment artifact."""
