"""placeholder"""
def design_actuators(problem, starts=None):
    raise NotImplementedError
