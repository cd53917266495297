"""placeholder"""
def load_profile(path): raise NotImplementedError
