"""The estimator (pure math): measurements in, fitted axis lines, DH tables, joint errors and clock fits out."""
