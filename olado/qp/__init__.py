"""The QP layer: the stage-structured QP (paper 001 sec. 4.2.2), olado's interior-point QP methods
whose Newton steps are KKT back-end solves, and adapters to external QP solvers."""
