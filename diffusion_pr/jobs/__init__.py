"""Jobs built on the theory and the GFMD reference: the paper's Fig. 1 and its reference data."""
