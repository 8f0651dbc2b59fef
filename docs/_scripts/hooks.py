"""mkdocs hooks: publish the generated benchmark report (benchmarks/results/) inside the site.

`python -m benchmarks` writes its full report, plots and CSVs to benchmarks/results/ and a
headline copy to docs/benchmarks.md, which links the full report as
`../benchmarks/results/README.md` (outside the docs folder, where GitHub finds it). Here the
results folder is added to the site as `benchmarks/results/` and that one link is rewritten,
so the generated files stay untouched and `mkdocs build --strict` resolves every link.
"""

import os

from mkdocs.structure.files import File


ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RESULTS = os.path.join(ROOT, "benchmarks", "results")
SITE_DIR = "benchmarks/results"


def on_files(files, config):
    for name in sorted(os.listdir(RESULTS)):
        if name.endswith((".md", ".png", ".csv")):
            files.append(
                File(
                    f"{SITE_DIR}/{name}",
                    src_dir=os.path.dirname(os.path.dirname(RESULTS)),
                    dest_dir=config["site_dir"],
                    use_directory_urls=config["use_directory_urls"],
                )
            )
    return files


def on_page_markdown(markdown, page, config, files):
    if page.file.src_uri == "benchmarks.md":
        markdown = markdown.replace("](../benchmarks/results/", "](benchmarks/results/")
    return markdown
