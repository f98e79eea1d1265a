"""The structure-exploiting SQP method (paper 001 sec. 4.2): the SQP loop and its Hessian approximations."""
