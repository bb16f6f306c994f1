"""The twin's report (placeholder until written)."""


def write_twin_report(result, out_dir):
    raise NotImplementedError
