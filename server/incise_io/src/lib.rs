//! NIfTI-1 and INRIMAGE-4 label volumes (being written).
