// `slurry resume` (resume_command.h): a run of the scene its newest checkpoint names.
#include "resume_command.h"

namespace slurry::cli {

void ResumeCommand::add(CLI::App& parent) {
  app = parent.add_subcommand("resume", "Continue the run whose checkpoints are in DIR (its scene file is read again)");
  app->add_option("directory", request.resume_dir, "Output directory holding checkpoint_NNNN.slc files")->required();
  app->add_option("--frames,-f", numbers.frames, "Last frame of the run (replaces output.frames)");
  app->add_option("--threads,-t", numbers.threads, "Worker threads (0 = all cores)");
  app->add_option("--memory-limit", numbers.memory, "Memory limit in GiB (replaces limits.memory_gb)");
  app->add_flag("--ascii", request.ascii, "Write ASCII PLY instead of binary");
  app->add_flag("--quiet,-q", request.quiet, "No progress output");
  app->add_flag("--force", request.force, "Accept checkpoints written for another version of the scene file");
}

}  // namespace slurry::cli
