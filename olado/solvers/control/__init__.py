"""Control-space and dynamic-programming methods: the reduced problem J(u) with adjoint
derivatives (gradient, conjugate directions, variable metric, truncated Newton), projected
descent (pdmin), DDP and stagewise Newton, and the penalty / augmented Lagrangian wrapper around them."""
