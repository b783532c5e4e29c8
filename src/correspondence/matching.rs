//! Nearest-neighbour matching of FPFH descriptors.
