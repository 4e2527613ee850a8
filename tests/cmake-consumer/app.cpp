// The C++ wrapper from the installed headers: an error carries the library's status and text.
#include <sie.hpp>

#include <cstdio>

int main() {
    sie::Context context;
    try {
        context.set_max_iterations(0);
    } catch (const sie::Error &error) {
        std::printf("%s\n", error.what());
        return error.status() == sie::Status::InvalidArgument ? 0 : 1;
    }
    return 1;
}
