"""Engine: an instance of a compiled chart, the plant (instances + process image + drivers),
the plant's names, and the simulator on a virtual clock."""
