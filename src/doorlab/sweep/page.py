def build_sweep_page(frame, spec, out_dir, *, wall_time_s=None):
    return None
