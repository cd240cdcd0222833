"""What a run leaves: its folder (:func:`doorlab.outputs.runs.run_to_folder`), the plots, the
3-D replay and the pages' machinery (Jinja2).
"""
