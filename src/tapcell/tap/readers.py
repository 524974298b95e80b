def read_tap_file(p): pass
def tap_to_json_dict(t,a=None): pass
