"""General NLP solvers on the flat sparse view of a DOCP (StructuredNLP): IPOPT and SciPy."""
