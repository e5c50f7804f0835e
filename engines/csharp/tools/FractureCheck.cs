// FractureCheck - conformance driver of the C# reader (used by the fracture tests).
//
//   mono FractureCheck.exe HEADER BINARY [--names] [--skip-crc] [--compact] < impacts
//   mono FractureCheck.exe --bench ROUNDS HEADER BINARY [--compact] < impacts
//
// Same line protocol as engines/c/tools/fracture_check.c: impacts are 7 hex IEEE-754 doubles
// (point, impulse, threshold or "-"); answers "ok <site> <num_groups> g ... b ... a ... d ..."
// or "error <status>"; a file that does not load prints "load-error <message>" and exits with 2.
// Each impact is also projected without displacements: an answer that differs prints "error
// inconsistent". --compact loads without the jump table (the other projection path).
// --bench times every impact ROUNDS times (Stopwatch around each Project call, groups only) and
// prints "median_ns <x> p99_ns <x> calls <n>", like fracture_bench.c.
//
// MIT licence, Copyright (c) fracture developers.

using System;
using System.IO;
using System.Globalization;
using System.Text;
using Fracture;

static class FractureCheck
{
    static double FromBits(string hex)
    {
        return BitConverter.Int64BitsToDouble(unchecked((long)Convert.ToUInt64(hex, 16)));
    }

    static string Bits(double value)
    {
        return BitConverter.DoubleToInt64Bits(value).ToString("x16");
    }

    static int Main(string[] args)
    {
        bool names = Array.IndexOf(args, "--names") >= 0, skipCrc = Array.IndexOf(args, "--skip-crc") >= 0;
        bool compact = Array.IndexOf(args, "--compact") >= 0;
        int bench = Array.IndexOf(args, "--bench"), rounds = 0;
        if (bench >= 0 && (bench + 1 >= args.Length || !int.TryParse(args[bench + 1], out rounds) || rounds < 1))
            bench = -2;
        string[] paths = Array.FindAll(args, a => !a.StartsWith("--") && (bench < 0 || a != args[bench + 1]));
        if (paths.Length != 2 || bench == -2)
        {
            Console.Error.WriteLine("usage: FractureCheck [--bench ROUNDS] HEADER BINARY [--names] [--skip-crc] [--compact] < impacts");
            return 64;
        }
        FractureRuntime runtime;
        string error;
        if (!FractureRuntime.TryLoad(File.ReadAllBytes(paths[0]), File.ReadAllBytes(paths[1]), out runtime, out error,
                                     !skipCrc, compact))
        {
            Console.WriteLine("load-error " + error);
            return 2;
        }
        if (bench >= 0)
            return Bench(runtime, rounds);
        var output = new StringBuilder();
        if (names)
        {
            output.Append("names");
            foreach (string name in runtime.FragmentNames)
            {
                byte[] utf8 = Encoding.UTF8.GetBytes(name);
                output.Append(' ').Append(utf8.Length == 0 ? "-" : BitConverter.ToString(utf8).Replace("-", "").ToLowerInvariant());
            }
            output.Append('\n');
        }
        var impact = new FractureImpact(runtime);
        var groupsOnly = new FractureImpact(runtime) { ComputeDisplacement = false };
        string line;
        while ((line = Console.In.ReadLine()) != null)
        {
            string[] t = line.Split(new[] { ' ', '\t' }, StringSplitOptions.RemoveEmptyEntries);
            if (t.Length == 0)
                continue;
            double threshold = t[6] == "-" ? runtime.DefaultThreshold : FromBits(t[6]);
            FractureStatus status = runtime.Project(FromBits(t[0]), FromBits(t[1]), FromBits(t[2]), FromBits(t[3]),
                                                    FromBits(t[4]), FromBits(t[5]), threshold, impact);
            if (status != FractureStatus.Ok)
            {
                output.Append("error ").Append(status).Append('\n');
                continue;
            }
            runtime.Project(FromBits(t[0]), FromBits(t[1]), FromBits(t[2]), FromBits(t[3]), FromBits(t[4]),
                            FromBits(t[5]), threshold, groupsOnly);
            if (groupsOnly.Site != impact.Site || groupsOnly.NumGroups != impact.NumGroups ||
                groupsOnly.NumBroken != impact.NumBroken || !Same(groupsOnly.Groups, impact.Groups))
            {
                output.Append("error inconsistent\n");
                continue;
            }
            output.Append("ok ").Append(impact.Site).Append(' ').Append(impact.NumGroups).Append(" g");
            foreach (int g in impact.Groups)
                output.Append(' ').Append(g);
            output.Append(" b");
            for (int m = 0; m < impact.Broken.Length; m++)
                if (impact.Broken[m])
                    output.Append(' ').Append(m);
            output.Append(" a");
            foreach (double a in impact.Alpha)
                output.Append(' ').Append(Bits(a));
            output.Append(" d");
            foreach (double x in impact.Displacement)
                output.Append(' ').Append(Bits(x));
            output.Append('\n');
        }
        Console.Out.Write(output.ToString());
        return 0;
    }

    static bool Same(int[] a, int[] b)
    {
        for (int i = 0; i < a.Length; i++)
            if (a[i] != b[i])
                return false;
        return true;
    }

    static int Bench(FractureRuntime runtime, int rounds)
    {
        var hits = new System.Collections.Generic.List<double[]>();
        string line;
        while ((line = Console.In.ReadLine()) != null)
        {
            string[] t = line.Split(new[] { ' ', '\t' }, StringSplitOptions.RemoveEmptyEntries);
            if (t.Length < 7)
                continue;
            var hit = new double[7];
            for (int i = 0; i < 6; i++)
                hit[i] = FromBits(t[i]);
            hit[6] = t[6] == "-" ? runtime.DefaultThreshold : FromBits(t[6]);
            hits.Add(hit);
        }
        var impact = new FractureImpact(runtime) { ComputeDisplacement = false };
        var times = new double[hits.Count * rounds];
        double tick = 1e9 / System.Diagnostics.Stopwatch.Frequency;
        int calls = 0;
        for (int r = 0; r < rounds + 1; r++) // round 0 warms up the JIT, not timed
            foreach (double[] h in hits)
            {
                long t0 = System.Diagnostics.Stopwatch.GetTimestamp();
                runtime.Project(h[0], h[1], h[2], h[3], h[4], h[5], h[6], impact);
                long t1 = System.Diagnostics.Stopwatch.GetTimestamp();
                if (r > 0)
                    times[calls++] = (t1 - t0) * tick;
            }
        Array.Sort(times);
        Console.WriteLine(string.Format(CultureInfo.InvariantCulture, "median_ns {0:F1} p99_ns {1:F1} calls {2}",
                                        times[calls / 2], times[(int)(0.99 * (calls - 1))], calls));
        return 0;
    }
}
