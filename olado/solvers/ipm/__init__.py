"""IPOPT's primal-dual interior-point filter method on the Riccati KKT back-end (docs/interior-point-nlp.md)."""
