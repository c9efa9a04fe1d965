#include "common/cli/cli.h"

#include <iostream>
#include <string>
#include <vector>

#include "exoview_version.h"

namespace exo::cli {

std::string Version() { return std::string(EXOVIEW_VERSION) + " (git " + EXOVIEW_GIT + ")"; }

void Setup(CLI::App& app) {
  app.set_version_flag("--version", Version(), "print the version and exit");
  app.allow_extras(false);
  app.set_help_flag("-h,--help", "print this help and exit");
  // --help shows every option's default (the value it has before parsing).
  app.option_defaults()->always_capture_default();
}

std::optional<int> Parse(CLI::App& app, int argc, const char* const* argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e, std::cout, std::cerr);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e, std::cout, std::cerr);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e, std::cout, std::cerr);
  } catch (const CLI::ParseError& e) {
    // CLI11 checks required options before unknown ones: name the unknown flag first, since it
    // is the likelier mistake ("--bogus 3" on a binary with a required --out).
    const std::vector<std::string> unknown = app.remaining();
    if (!unknown.empty() && dynamic_cast<const CLI::ExtrasError*>(&e) == nullptr) {
      std::cerr << app.get_name() << ": " << CLI::ExtrasError(unknown).what()
                << "\nRun with --help for the flags.\n";
      return 2;
    }
    std::cerr << app.get_name() << ": " << e.what() << "\nRun with --help for the flags.\n";
    return 2;
  }
  return std::nullopt;
}

}  // namespace exo::cli
